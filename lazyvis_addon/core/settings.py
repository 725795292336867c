"""Render settings: one dataclass holding every default of the core.

The Blender layer maps ``scene.lazyvis`` onto this in one function; the command line maps its flags
onto it. Nothing else in the core has a default of its own.
"""

from __future__ import annotations

from dataclasses import dataclass, fields, replace

from .film import FILTER_TYPES, half_extent

INTEGRATORS = ("analytic", "reduced_mc", "standard_mc", "reference")
GLOSSY_INTEGRATORS = ("ltc", "ltc_cv", "phong", "mc")
VISIBILITY_METHODS = ("silhouettes", "blocker_map")


@dataclass(frozen=True)
class Settings:
    """Every knob of the renderer core.

    Attributes
    ----------
    integrator : str
        ``"analytic"`` (blocker map, Lambert's polygon formula over the visible pieces: exact when no
        blocker was missed), ``"reduced_mc"`` (blocker map, Monte Carlo over the visible pieces, paper 3.3),
        ``"standard_mc"`` (shadow rays over the whole light: the paper's baseline) or ``"reference"``
        (every triangle is a candidate blocker: exact and slow, the oracle for tests).
    glossy_integrator : str
        How the analytic and reference integrators integrate GGX lobes (Principled and Glossy BSDFs) over
        the visible pieces: ``"ltc"`` (linearly transformed cosines, Heitz et al. 2016: analytic, a few
        percent off at grazing views), ``"ltc_cv"`` (the default: LTC as a control variate, the shape of
        Cycles' lobe against the fitted one integrated by a Gauss rule over the pieces in LTC's cosine
        domain with each closure's Fresnel, roughness 0.05 and up; deterministic, within Cycles' noise on the
        glossy floor where LTC is 1-6 % off, 1.3-1.5x LTC's render time), ``"phong"`` (the paper's Phong lobes with a peak-matched exponent:
        analytic, a cruder shape) or ``"mc"`` (``mc_samples`` directions over the visible pieces,
        unbiased). Diffuse lobes stay analytic. The two MC integrators sample every lobe.
    visibility : str
        How the analytic integrator finds what each pixel sees of a light. ``"silhouettes"`` (default):
        every edge that may cross the light is found by culling an edge tree against groups of pixels
        (complete by construction, whatever the blockers' size), and the visible region comes out exactly
        from the silhouette arcs crossing the light and one reference depth (``silhouettes``); no pass 1,
        no shadow-ray seeds, no verification needed. ``"blocker_map"``: the paper's pass 1 (shadow rays
        and flood fill, which miss blockers no ray hits) and pass 2 by blocker subtraction. The Monte
        Carlo glossy integral and the other integrators always take the blocker map (they sample pieces).
    shadow_rays : int
        Shadow rays per pixel and light in pass 1 (blocker detection), stratified over the light's solid angle.
    verify_rays : int
        Verification rays per pixel and light, sampled over what the blocker map leaves visible: a hit
        is a blocker the map missed, which is then flood-filled and the pixels it reaches re-shaded
        (beyond the paper). The error from missed blockers falls towards zero as they grow; 0 (the default)
        turns verification off. Only the window's pixels are verified, so a window equals the full frame
        exactly only without verification.
        Anti-aliasing samples that see another surface than their pixel's centre (whose inherited list
        is made for the wrong surface) are always verified, every sample when this is > 0: 4 rays each
        (``shading.SAMPLE_VERIFY_RAYS``), a pair found at one joining all the pixel's samples.
    refine_rounds : int
        How many times verification may add blockers and re-shade.
    mc_samples : int
        Samples per pixel and light for the two Monte Carlo integrators.
    connectivity : int
        Flood-fill neighbourhood, 8 (the paper's text) or 4 (its Fig. 3 pseudo-code).
    aa_samples : int
        Anti-aliasing: samples for pixels at edges (another polygon, material or a radiance step in
        their neighbourhood) on average: each gets from 2 up to 4 times that many, in proportion to its
        radiance step (``antialias.allocate_samples``), placed by the pixel filter and pooled with the
        neighbouring edge pixels' samples under its footprint; 1 shades pixel centres only. The samples
        per unit of radiance step are the whole frame's (from every pixel of a frame of up to 65,536, from
        1,024 patches of 3 x 3 pixels spread over a larger one, where the mean is then about this), so
        that a border or a tile allocates as the frame does. With coverage rays, a pixel whose pilot
        samples show surfaces that vary less than the step between them draws fewer
        (``antialias.surface_spread``: the step is the coverage rays' to resolve), so the mean is at most this.
    aa_coverage_rays : int
        Camera rays per anti-aliased pixel that only find which surface they hit (no shading): the pixel
        is the sum over the surfaces under its filter (connected meshes, told apart by material too) of
        the fraction of these rays each covers times the mean of the shaded samples on it
        (``antialias.pool_samples``). A silhouette edge then costs a shaded sample on each side instead of
        many: on the fence bench 2 samples with 16 coverage rays err 3x less than 2 samples alone.
        A pixel gets at least 4 coverage rays per shaded sample (``antialias.COVERAGE_RAYS_PER_SAMPLE``),
        its samples among them; 0 turns coverage off (the filtered mean of the samples alone).
    aa_settle_tolerance : float
        An edge pixel first shades ``antialias.PILOT_SAMPLES`` of its samples; when those, its centre and
        its coverage rays see one surface and every pilot sample is within this fraction of the pixel's
        scale (the larger of its centre's brightest channel and its step to a neighbour) of the centre,
        the pixel keeps the pilot (its error is then below that fraction) and draws no more
        (``antialias.settled_pixels``). 0 shades every allocated sample.
    filter_width : float
        Pixel filter width in pixels, Cycles' Film > Pixel Filter > Width (``scene.cycles.filter_width``;
        1.5 default): the Blackman-Harris window's radius.
    filter_type : str
        Cycles' pixel filter type: ``"BLACKMAN_HARRIS"`` (default), ``"GAUSSIAN"`` or ``"BOX"`` (Cycles forces
        a box to width 1: one pixel, nothing borrowed from neighbours).
    aa_threshold : float
        Relative radiance difference between neighbours that marks a pixel for anti-aliasing.
    extend_fill : bool
        Also store a pair in the boundary pixels where its overlap test first fails (paper section 4.4),
        so that a pixel's blocker list holds for every point seen through the pixel (anti-aliasing).
    umbra_detection : bool
        Mark a light hidden at a pixel when one projected blocker surrounds it (paper section 5).
    seed : int
        Random seed; random numbers derive from (seed, frame, global pixel), so tiles match the full frame.
    frame : int
        Frame number, mixed into the random numbers.
    transparent_background : bool
        Background pixels get RGBA 0 instead of the background colour with alpha 1.
    memory_budget_mb : float
        Working memory the passes may use for their batches; a budget too small to render fails clearly.
    pixel_batch : int
        Pixels per batch in pass 2 and for camera rays (progress and cancel granularity).
    merge_quads : bool
        Merge coplanar triangle pairs that form convex quads into one blocker polygon, and clip by the
        silhouette of each closed convex part (a box, a post) instead of by each of its faces: fewer pairs
        and pieces; the image is the same up to rounding, or more exact where a list lacks a part's face.
    threads : int
        Worker threads for the batched stages; 0 means one per core.
    window_margin : int
        Blocker Map visibility only: when rendering a window (border or tile), pass 1 also covers this
        many pixels of the frame around it, so that blockers found just outside the window flood into it
        as they would in the full frame. A margin as large as the frame makes a window exactly equal to
        the full frame's pixels. The default visibility (silhouettes) needs none: a window is always the
        frame's pixels, its anti-aliasing's own margin worked out from the filter (``frame.aa_margin``).
    """

    integrator: str = "analytic"
    glossy_integrator: str = "ltc_cv"
    visibility: str = "silhouettes"
    shadow_rays: int = 4
    mc_samples: int = 16
    verify_rays: int = 0
    refine_rounds: int = 2
    connectivity: int = 8
    umbra_detection: bool = True
    extend_fill: bool = False
    aa_samples: int = 16
    aa_coverage_rays: int = 16
    aa_settle_tolerance: float = 1e-3
    filter_width: float = 1.5
    filter_type: str = "BLACKMAN_HARRIS"
    aa_threshold: float = 0.1
    seed: int = 0
    frame: int = 0
    transparent_background: bool = False
    memory_budget_mb: float = 2048.0
    pixel_batch: int = 16384
    window_margin: int = 32
    threads: int = 0
    merge_quads: bool = True

    def __post_init__(self) -> None:
        if self.integrator not in INTEGRATORS:
            raise ValueError(f"integrator must be one of {', '.join(INTEGRATORS)}, not {self.integrator!r}")
        if self.glossy_integrator not in GLOSSY_INTEGRATORS:
            raise ValueError(f"glossy_integrator must be one of {', '.join(GLOSSY_INTEGRATORS)}, "
                             f"not {self.glossy_integrator!r}")
        if self.visibility not in VISIBILITY_METHODS:
            raise ValueError(f"visibility must be one of {', '.join(VISIBILITY_METHODS)}, not {self.visibility!r}")
        if self.connectivity not in (4, 8):
            raise ValueError(f"connectivity must be 4 or 8, not {self.connectivity!r}")
        for name in ("verify_rays", "refine_rounds", "aa_coverage_rays"):
            value = getattr(self, name)
            if not isinstance(value, int) or value < 0:
                raise ValueError(f"{name} must be a non-negative integer, not {value!r}")
        if self.filter_type not in FILTER_TYPES:
            raise ValueError(f"filter_type must be one of {', '.join(FILTER_TYPES)}, not {self.filter_type!r}")
        if not (self.filter_width > 0 and self.aa_threshold >= 0 and self.aa_settle_tolerance >= 0):
            raise ValueError("filter_width must be positive, aa_threshold and aa_settle_tolerance non-negative")
        for name in ("shadow_rays", "mc_samples", "pixel_batch", "aa_samples"):
            value = getattr(self, name)
            if not isinstance(value, int) or value < 1:
                raise ValueError(f"{name} must be a positive integer, not {value!r}")
        if not isinstance(self.threads, int) or self.threads < 0:
            raise ValueError(f"threads must be a non-negative integer, not {self.threads!r}")
        if not isinstance(self.window_margin, int) or self.window_margin < 0:
            raise ValueError(f"window_margin must be a non-negative integer, not {self.window_margin!r}")
        if not self.memory_budget_mb > 0:
            raise ValueError(f"memory_budget_mb must be positive, not {self.memory_budget_mb!r}")

    @property
    def uses_silhouettes(self) -> bool:
        """Pass 2 by silhouette arcs (no blocker map): the analytic integrator with an analytic glossy lobe."""
        return self.visibility == "silhouettes" and self.integrator == "analytic" and self.glossy_integrator != "mc"

    @property
    def fills_boundary(self) -> bool:
        """Pass 1 stores pairs in the boundary ring too: asked for, or needed by anti-aliasing."""
        return self.extend_fill or self.aa_samples > 1

    @property
    def filter_reach(self) -> float:
        """How far (pixels) a camera sample may land from its pixel's centre: the filter's half support."""
        return half_extent(self.effective_filter_width, self.filter_type)

    @property
    def effective_filter_width(self) -> float:
        """The width Cycles samples with (a box is always 1 pixel wide)."""
        return 1.0 if self.filter_type == "BOX" else self.filter_width

    def replace(self, **changes) -> "Settings":
        """A copy with some fields changed (validated again)."""
        return replace(self, **changes)

    @classmethod
    def field_names(cls) -> tuple[str, ...]:
        return tuple(f.name for f in fields(cls))
