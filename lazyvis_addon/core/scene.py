"""The scene the core renders: plain numpy arrays, no Blender.

Vocabulary used in every docstring of the core: T triangles, M materials, L lights, V polygon vertices
(padded to the largest light), H x W image (the rendered window), N rays or pixels.
World units are metres; radiance is W m^-2 sr^-1 per colour channel (linear, scene-referred).

Conventions follow Blender: the camera looks along its local -Z with +Y up; image row 0 is the top row.
"""

from __future__ import annotations

import dataclasses
import math
from dataclasses import dataclass, field

import numpy as np

from .progress import Progress
from .texture import ImageTexture

PROJECTIONS = ("perspective", "orthographic")


def _as_float_array(name: str, value, shape_tail: tuple[int, ...]) -> np.ndarray:
    array = np.asarray(value, dtype=np.float64)
    if array.ndim != len(shape_tail) + 1 or tuple(array.shape[1:]) != shape_tail:
        want = " x ".join(["N"] + [str(s) for s in shape_tail])
        raise ValueError(f"{name} must have shape {want}, got {array.shape}")
    return array


def _require_finite(name: str, array: np.ndarray) -> None:
    bad = ~np.isfinite(array)
    if bad.any():
        flat = np.flatnonzero(bad.reshape(len(array), -1).any(axis=1)) if array.ndim > 1 else np.flatnonzero(bad)
        shown = ", ".join(str(i) for i in flat[:5]) + (" ..." if len(flat) > 5 else "")
        raise ValueError(f"{name} contain NaN or infinite values (entries {shown}; {len(flat)} in all)")


@dataclass
class Camera:
    """A pinhole (perspective) or orthographic camera.

    Attributes
    ----------
    world_from_camera : (4, 4) float64
        Camera-to-world transform; the camera looks along its local -Z, +Y is up, +X right.
    width, height : int
        Full-frame resolution in pixels.
    projection : str
        ``"perspective"`` or ``"orthographic"``.
    screen_window : (4,) float64
        ``(left, right, bottom, top)`` of the full frame: for a perspective camera on the plane z = -1 in
        camera space (so tan of the half angles), for an orthographic one in camera-space units.
    window : (4,) int
        ``(x0, y0, x1, y1)`` pixel window of the full frame to render (x to the right, y down from the top
        row, exclusive ends): a border or a tile. Random numbers use full-frame pixel coordinates, and
        anti-aliasing renders the margin its pixels read and allocates samples at the frame's scale
        (``frame.aa_margin``, ``antialias.FrameScale``), so a window renders exactly the pixels of the
        full frame (with the Blocker Map visibility, up to what its flood fill finds outside the window).
    clip_start, clip_end : float
        Blender's Clip Start and End (m, along the viewing axis): as in Cycles, camera rays start on the
        plane clip_start in front of the camera and end on the plane clip_end (``camera.camera_rays``).
    """

    world_from_camera: np.ndarray
    width: int
    height: int
    projection: str = "perspective"
    screen_window: np.ndarray = field(default_factory=lambda: np.array([-0.5, 0.5, -0.5, 0.5]))
    window: tuple[int, int, int, int] | None = None
    clip_start: float = 0.0
    clip_end: float = np.inf

    def __post_init__(self) -> None:
        self.world_from_camera = np.asarray(self.world_from_camera, dtype=np.float64).reshape(4, 4)
        self.clip_start, self.clip_end = float(self.clip_start), float(self.clip_end)
        if not (0.0 <= self.clip_start < self.clip_end):
            raise ValueError(f"camera clip start {self.clip_start} and end {self.clip_end} must satisfy "
                             "0 <= start < end")
        self.screen_window = np.asarray(self.screen_window, dtype=np.float64).reshape(4)
        self.width, self.height = int(self.width), int(self.height)
        if self.projection not in PROJECTIONS:
            raise ValueError(f"camera projection must be one of {PROJECTIONS}, not {self.projection!r}")
        if self.width < 1 or self.height < 1:
            raise ValueError(f"camera resolution must be at least 1 x 1, got {self.width} x {self.height}")
        if not (np.isfinite(self.world_from_camera).all() and np.isfinite(self.screen_window).all()):
            raise ValueError("camera transform or screen window contains NaN or infinite values")
        axes = self.world_from_camera[:3, :3]
        if not abs(np.linalg.det(axes)) > 1e-12 * max(float(np.abs(axes).max()), 1e-300) ** 3:
            raise ValueError("camera transform is singular (a zero scale on the camera?)")
        left, right, bottom, top = self.screen_window
        if not (right > left and top > bottom):
            raise ValueError(f"camera screen window must have right > left and top > bottom, got {self.screen_window}")
        if self.window is None:
            self.window = (0, 0, self.width, self.height)
        x0, y0, x1, y1 = (int(v) for v in self.window)
        if not (0 <= x0 < x1 <= self.width and 0 <= y0 < y1 <= self.height):
            raise ValueError(f"pixel window {self.window} is empty or outside the {self.width} x {self.height} frame")
        self.window = (x0, y0, x1, y1)

    @classmethod
    def perspective(cls, world_from_camera, width: int, height: int, fov: float,
                    shift: tuple[float, float] = (0.0, 0.0), pixel_aspect: float = 1.0,
                    window=None) -> "Camera":
        """A perspective camera whose full field of view ``fov`` (radians) spans the longer image side,
        as Blender's sensor fit AUTO does; ``shift`` in units of the longer side, as Blender's lens shift."""
        half = np.tan(0.5 * fov)
        return cls(world_from_camera, width, height, "perspective",
                   _fit_window(half, width, height, shift, pixel_aspect), window)

    @classmethod
    def orthographic(cls, world_from_camera, width: int, height: int, ortho_scale: float,
                     shift: tuple[float, float] = (0.0, 0.0), pixel_aspect: float = 1.0,
                     window=None) -> "Camera":
        """An orthographic camera whose view spans ``ortho_scale`` units along the longer image side."""
        return cls(world_from_camera, width, height, "orthographic",
                   _fit_window(0.5 * ortho_scale, width, height, shift, pixel_aspect), window)

    @property
    def window_shape(self) -> tuple[int, int]:
        """(H, W) of the rendered window."""
        x0, y0, x1, y1 = self.window
        return (y1 - y0, x1 - x0)

    @property
    def position(self) -> np.ndarray:
        return self.world_from_camera[:3, 3].copy()


def _fit_window(half_long: float, width: int, height: int, shift, pixel_aspect: float) -> np.ndarray:
    """Screen window with the longer side (in aspect-corrected pixels) spanning [-half_long, half_long]."""
    aspect_width, aspect_height = width * pixel_aspect, float(height)
    if aspect_width >= aspect_height:
        half_x, half_y = half_long, half_long * aspect_height / aspect_width
    else:
        half_x, half_y = half_long * aspect_width / aspect_height, half_long
    dx, dy = 2.0 * half_long * shift[0], 2.0 * half_long * shift[1]
    return np.array([-half_x + dx, half_x + dx, -half_y + dy, half_y + dy])


@dataclass
class Lights:
    """Planar convex polygon lights of constant radiance.

    Attributes
    ----------
    vertices : (L, V, 3) float64
        Polygon vertices in world space, padded to V by repeating the last vertex. Ordered
        counter-clockwise about the emitting normal ``normalize((v1 - v0) x (v2 - v0))``.
    vertex_count : (L,) int64
        Real vertex count of each light (3 <= count <= V).
    radiance : (L, 3) float64
        Emitted radiance per colour channel, W m^-2 sr^-1.
    two_sided : (L,) bool
        Emit from both sides (mesh emitters); one-sided lights emit to the side of their normal only.
    cast_shadow : (L,) bool or None
        False: nothing blocks the light (Blender's Cast Shadow off); None: all cast shadows.
    spread : (L,) float64 or None
        Cycles' area light Spread (radians, 0..pi): emission towards angle t from the normal is weighted by
        max(tan(s/2) - tan t, 0) / (tan(s/2) - s/2) (``facing.spread_weights``); None or pi: Lambertian.
    lobes : (L,) int64 or None
        The BSDF lobes the light reaches, LOBE_DIFFUSE | LOBE_GLOSSY (Blender's Ray Visibility > Diffuse and
        Glossy of the light's object); None: both.
    """

    vertices: np.ndarray
    vertex_count: np.ndarray
    radiance: np.ndarray
    two_sided: np.ndarray
    cast_shadow: np.ndarray | None = None
    spread: np.ndarray | None = None
    lobes: np.ndarray | None = None

    def __post_init__(self) -> None:
        if self.cast_shadow is None:
            self.cast_shadow = np.ones(len(self.vertex_count), bool)
        if self.spread is None:
            self.spread = np.full(len(self.vertex_count), np.pi)
        self.lobes = _lobes(self.lobes, len(self.vertex_count))

    @classmethod
    def from_polygons(cls, polygons, radiance, two_sided=None) -> "Lights":
        """Lights from a list of (V_i, 3) vertex arrays, (L, 3) radiance and optional (L,) two-sided flags."""
        polygons = [np.asarray(p, dtype=np.float64).reshape(-1, 3) for p in polygons]
        count = len(polygons)
        vmax = max([len(p) for p in polygons], default=3)
        vertices = np.zeros((count, max(vmax, 3), 3))
        for index, poly in enumerate(polygons):  # one per light, not per pixel
            if len(poly) < 3:
                raise ValueError(f"light {index} has {len(poly)} vertices; a polygon light needs at least 3")
            vertices[index, :len(poly)] = poly
            vertices[index, len(poly):] = poly[-1]
        radiance = np.asarray(radiance, dtype=np.float64).reshape(count, 3)
        two_sided = np.zeros(count, bool) if two_sided is None else np.asarray(two_sided, bool).reshape(count)
        return cls(vertices, np.array([len(p) for p in polygons], dtype=np.int64), radiance, two_sided)

    @classmethod
    def empty(cls) -> "Lights":
        return cls(np.zeros((0, 3, 3)), np.zeros(0, np.int64), np.zeros((0, 3)), np.zeros(0, bool))

    @classmethod
    def concat(cls, parts: list["Lights"]) -> "Lights":
        """The lights of ``parts`` in order, padded to the widest polygon."""
        if not parts:
            return cls.empty()
        width = max(p.vertices.shape[1] for p in parts)

        def padded(vertices):
            return np.concatenate([vertices, np.repeat(vertices[:, -1:], width - vertices.shape[1], axis=1)], axis=1) \
                if len(vertices) else np.zeros((0, width, 3))

        return cls(np.concatenate([padded(p.vertices) for p in parts]),
                   *(np.concatenate([getattr(p, name) for p in parts])
                     for name in ("vertex_count", "radiance", "two_sided", "cast_shadow", "spread", "lobes")))

    def __len__(self) -> int:
        return len(self.vertex_count)

    def subset(self, keep: np.ndarray) -> "Lights":
        return Lights(self.vertices[keep], self.vertex_count[keep], self.radiance[keep], self.two_sided[keep],
                      self.cast_shadow[keep], self.spread[keep], self.lobes[keep])


# The BSDF lobes a light reaches (``Lights.lobes``, ``FacingLights.lobes``, ``EmitterHulls.lobes``): bits.
LOBE_DIFFUSE, LOBE_GLOSSY = 1, 2
LOBES_ALL = LOBE_DIFFUSE | LOBE_GLOSSY


def _lobes(lobes, count: int) -> np.ndarray:
    """(count,) int64 lobe bits, LOBES_ALL where None; a ValueError for bits outside LOBES_ALL."""
    if lobes is None:
        return np.full(count, LOBES_ALL, np.int64)
    lobes = np.asarray(lobes, dtype=np.int64).reshape(count)
    if ((lobes & ~LOBES_ALL) != 0).any() or (lobes < 0).any():
        raise ValueError(f"light lobes must be bits of {LOBES_ALL} (1 diffuse, 2 glossy)")
    return lobes


# Kinds of ``FacingLights``: how the cap of directions a receiver sees is sized.
FACING_DISK, FACING_SPHERE, FACING_SUN = 0, 1, 2
FACING_KINDS = {"disk": FACING_DISK, "sphere": FACING_SPHERE, "sun": FACING_SUN}


@dataclass
class FacingLights:
    """Lights seen as a cap of directions that faces each shading point: Blender's point, spot and sun lights.

    Seen from a receiver x, each is a cap of uniform radiance (``facing`` builds its polygon per receiver):
    a disk of radius r facing x (a point or spot lamp with Soft Falloff on, Blender's default), half-angle
    atan(r / d) about the centre, d = |centre - x|; a sphere of radius r (Soft Falloff off), asin(r / d);
    a sun, half-angle ``radius`` about ``centre`` (then the unit direction towards the sun). Radius 0 is a
    hard light: a cap of ``facing.HARD_ANGLE``.

    Attributes
    ----------
    kind : (F,) int64           FACING_DISK, FACING_SPHERE or FACING_SUN.
    centre : (F, 3) float64     the lamp's centre (m); for a sun the direction towards it (any length).
    radius : (F,) float64       the lamp's radius (m); for a sun the cap's half-angle (radians).
    intensity : (F, 3) float64  per colour channel: a lamp's intensity I (W/sr; P / (4 pi) for Blender's
                                power P), a sun's irradiance E (W/m^2, Blender's Strength). The cap's
                                radiance is I / (pi r^2), or E / (pi sin^2(half-angle)).
    spot_frame : (F, 3, 3)      world offsets from the centre to the spot's local axes with its scale divided
                                out (local = spot_frame @ (x - centre)); the cone opens along local -Z.
    spot_cos_half : (F,)        cos(Spot Size / 2); below -1: no cone (a point lamp or a sun).
    spot_smooth : (F,)          Spot Blend * (1 - cos_half): the width of the mask's smoothstep in cos.
    cast_shadow : (F,) bool     False: nothing blocks the light (Cast Shadow off).
    lobes : (F,) int64          the BSDF lobes the light reaches (``Lights.lobes``).
    """

    kind: np.ndarray
    centre: np.ndarray
    radius: np.ndarray
    intensity: np.ndarray
    spot_frame: np.ndarray | None = None
    spot_cos_half: np.ndarray | None = None
    spot_smooth: np.ndarray | None = None
    cast_shadow: np.ndarray | None = None
    lobes: np.ndarray | None = None

    def __post_init__(self) -> None:
        self.kind = np.asarray(self.kind, dtype=np.int64).reshape(-1)
        count = len(self.kind)
        self.centre = np.asarray(self.centre, dtype=np.float64).reshape(count, 3)
        self.radius = np.asarray(self.radius, dtype=np.float64).reshape(count)
        self.intensity = np.asarray(self.intensity, dtype=np.float64).reshape(count, 3)
        self.spot_frame = np.broadcast_to(np.eye(3), (count, 3, 3)).copy() if self.spot_frame is None else \
            np.asarray(self.spot_frame, dtype=np.float64).reshape(count, 3, 3)
        self.spot_cos_half = np.full(count, -2.0) if self.spot_cos_half is None else \
            np.asarray(self.spot_cos_half, dtype=np.float64).reshape(count)
        self.spot_smooth = np.zeros(count) if self.spot_smooth is None else \
            np.asarray(self.spot_smooth, dtype=np.float64).reshape(count)
        self.cast_shadow = np.ones(count, bool) if self.cast_shadow is None else \
            np.asarray(self.cast_shadow, dtype=bool).reshape(count)
        self.lobes = _lobes(self.lobes, count)

    @classmethod
    def empty(cls) -> "FacingLights":
        return cls(np.zeros(0, np.int64), np.zeros((0, 3)), np.zeros(0), np.zeros((0, 3)))

    def spot(self, frame, size: float, blend: float) -> "FacingLights":
        """These lamps (one or more) as spots: ``frame`` (3, 3) world offsets to the spot's scaled local axes,
        Spot Size (full cone angle, radians) and Spot Blend (0..1)."""
        cos_half = math.cos(0.5 * min(max(size, 0.0), math.pi))
        count = len(self)
        return FacingLights(self.kind, self.centre, self.radius, self.intensity,
                            np.broadcast_to(np.asarray(frame, dtype=np.float64), (count, 3, 3)).copy(),
                            np.full(count, cos_half), np.full(count, min(max(blend, 0.0), 1.0) * (1.0 - cos_half)),
                            self.cast_shadow, self.lobes)

    def without_shadows(self) -> "FacingLights":
        """These lights with Cast Shadow off."""
        return FacingLights(self.kind, self.centre, self.radius, self.intensity, self.spot_frame, self.spot_cos_half,
                            self.spot_smooth, np.zeros(len(self), bool), self.lobes)

    def reaching(self, lobes: int) -> "FacingLights":
        """These lights reaching only the BSDF lobes ``lobes`` (LOBE_* bits)."""
        return FacingLights(self.kind, self.centre, self.radius, self.intensity, self.spot_frame, self.spot_cos_half,
                            self.spot_smooth, self.cast_shadow, np.full(len(self), lobes, np.int64))

    @classmethod
    def point(cls, centre, radius: float, intensity, soft_falloff: bool = True) -> "FacingLights":
        """One point lamp: centre (3,), radius (m), intensity (3,) W/sr per colour channel (P / (4 pi))."""
        return cls([FACING_DISK if soft_falloff else FACING_SPHERE], [centre], [radius],
                   np.broadcast_to(np.asarray(intensity, dtype=np.float64), (3,))[None])

    @classmethod
    def sun(cls, towards, angle: float, irradiance) -> "FacingLights":
        """One sun: the direction towards it (3,), its angular diameter (radians), irradiance (3,) W/m^2."""
        return cls([FACING_SUN], [towards], [0.5 * angle],
                   np.broadcast_to(np.asarray(irradiance, dtype=np.float64), (3,))[None])

    @classmethod
    def concat(cls, parts: list["FacingLights"]) -> "FacingLights":
        if not parts:
            return cls.empty()
        return cls(*(np.concatenate([getattr(p, name) for p in parts]) for name in
                     ("kind", "centre", "radius", "intensity", "spot_frame", "spot_cos_half", "spot_smooth",
                      "cast_shadow", "lobes")))

    def __len__(self) -> int:
        return len(self.kind)

    def subset(self, keep: np.ndarray) -> "FacingLights":
        return FacingLights(self.kind[keep], self.centre[keep], self.radius[keep], self.intensity[keep],
                            self.spot_frame[keep], self.spot_cos_half[keep], self.spot_smooth[keep],
                            self.cast_shadow[keep], self.lobes[keep])


@dataclass
class EmitterHulls:
    """Mesh emitters of uniform radiance grouped as hulls (``emitters``): a closed convex one is one light,
    any other two.

    From any point outside it, such an emitter is seen as its silhouette: the directions towards it are
    those of the polygon where the cone through the silhouette meets a plane, and every one carries its
    radiance. ``emitters.group_mesh_emitters`` finds them among a mesh's emitting triangles; pass 2 builds
    each receiver's polygon (``emitters.hull_polygons``), so a sphere of thousands of faces costs one light.

    Attributes
    ----------
    triangles : (K, 3, 3) float64   the emitters' faces (world space, m), wound outward.
    hull : (K,) int64               the emitter (row) of each face, ascending.
    radiance : (H, 3) float64       each emitter's radiance, W m^-2 sr^-1 per colour channel.
    lobes : (H,) int64              the BSDF lobes each reaches (``Lights.lobes``); None: both.
    convex : (H,) bool              True (the default): closed and convex, seen as its silhouette. False:
                                    any other emitter (a torus, a lamp shade), two-sided, seen as the
                                    silhouette of its vertices' convex hull less the directions through
                                    that hull that miss it (``emitters``).
    """

    triangles: np.ndarray
    hull: np.ndarray
    radiance: np.ndarray
    lobes: np.ndarray | None = None
    convex: np.ndarray | None = None

    def __post_init__(self) -> None:
        self.triangles = np.asarray(self.triangles, dtype=np.float64).reshape(-1, 3, 3)
        self.hull = np.asarray(self.hull, dtype=np.int64).reshape(-1)
        self.radiance = np.asarray(self.radiance, dtype=np.float64).reshape(-1, 3)
        self.lobes = _lobes(self.lobes, len(self.radiance))
        self.convex = np.ones(len(self.radiance), bool) if self.convex is None else \
            np.asarray(self.convex, bool).reshape(len(self.radiance))

    @classmethod
    def empty(cls) -> "EmitterHulls":
        return cls(np.zeros((0, 3, 3)), np.zeros(0, np.int64), np.zeros((0, 3)))

    def __len__(self) -> int:
        return len(self.radiance)

    def faces_of(self, row: int) -> np.ndarray:
        """The faces (k, 3, 3) of emitter ``row``."""
        return self.triangles[self.hull == row]

    def subset(self, keep: np.ndarray) -> "EmitterHulls":
        """The emitters ``keep`` (H,) bool, renumbered in order."""
        keep = np.asarray(keep, bool)
        renumber = np.cumsum(keep) - 1
        faces = keep[self.hull]
        return EmitterHulls(self.triangles[faces], renumber[self.hull[faces]], self.radiance[keep], self.lobes[keep],
                            self.convex[keep])


@dataclass
class Materials:
    """Material table, indexed by ``Scene.material_index``.

    One row describes the BSDFs LazyVis integrates (those of Cycles, evaluated as Cycles does; ``ggx.py``):

        f = diffuse_weight * w(ω_o) * base / π                               (diffuse)
          + principled * ((1 - metallic) * specular layer + metallic * metal) (Principled BSDF's GGX lobes)
          + glossy_colour * GGX                                              (a Glossy BSDF)

    with w = (1 - metallic) times the Principled layering weight for Principled rows, 1 otherwise.
    All GGX lobes of a row share its roughness (α = roughness²) and distribution (``multiscatter``).

    Attributes
    ----------
    albedo : (M, 3) float64
        Base colour in [0, 1]: the diffuse colour, and the metal's F0 for Principled rows.
    emission : (M, 3) float64 or None
        Radiance the surface emits towards the camera from both sides (mesh emitters, as Cycles does);
        their light on other surfaces comes from the matching two-sided polygon lights.
    texture_index : (M,) int64 or None
        Row of ``Scene.textures`` whose colour replaces the albedo (an Image Texture on the base colour),
        -1 for none.
    diffuse_weight : (M,) float64, default 1
        Weight of the diffuse closure (a Mix shader's factor; 0 for a pure Glossy BSDF).
    principled : (M,) bool, default False
        The row is a Principled BSDF: dielectric specular layer over the diffuse base, metal lobe.
    metallic, roughness, ior, specular_level : (M,) float64
        Principled inputs (Specular IOR Level: 0.5 is physical); roughness also of the Glossy BSDF.
        Defaults 0, 0.5, 1.5, 0.5.
    specular_tint : (M, 3) float64, default white
    glossy_colour : (M, 3) float64, default black
        Weight of a Glossy BSDF closure (its colour times a Mix shader's factor); black for none.
    multiscatter : (M,) bool, default True
        Multiscatter GGX (Cycles' default) rather than GGX.
    """

    albedo: np.ndarray
    emission: np.ndarray | None = None
    texture_index: np.ndarray | None = None
    diffuse_weight: np.ndarray | None = None
    principled: np.ndarray | None = None
    metallic: np.ndarray | None = None
    roughness: np.ndarray | None = None
    ior: np.ndarray | None = None
    specular_level: np.ndarray | None = None
    specular_tint: np.ndarray | None = None
    glossy_colour: np.ndarray | None = None
    multiscatter: np.ndarray | None = None

    # (field, default, trailing shape, dtype) of the per-row parameters after the albedo.
    PARAMETERS = (("emission", 0.0, (3,), np.float64), ("texture_index", -1, (), np.int64),
                  ("diffuse_weight", 1.0, (), np.float64), ("principled", False, (), bool),
                  ("metallic", 0.0, (), np.float64), ("roughness", 0.5, (), np.float64),
                  ("ior", 1.5, (), np.float64), ("specular_level", 0.5, (), np.float64),
                  ("specular_tint", 1.0, (3,), np.float64), ("glossy_colour", 0.0, (3,), np.float64),
                  ("multiscatter", True, (), bool))

    def __post_init__(self) -> None:
        self.albedo = np.asarray(self.albedo, dtype=np.float64).reshape(-1, 3)
        rows = len(self.albedo)
        for name, default, tail, dtype in self.PARAMETERS:
            value = getattr(self, name)
            if value is None:
                value = np.full((rows,) + tail, default, dtype)
            value = np.asarray(value, dtype=dtype)
            if value.size != rows * int(np.prod(tail)):
                raise ValueError(f"material {name} has {value.size} values for {rows} materials")
            setattr(self, name, value.reshape((rows,) + tail))

    @classmethod
    def diffuse(cls, albedo) -> "Materials":
        return cls(np.asarray(albedo, dtype=np.float64).reshape(-1, 3))

    @property
    def glossy(self) -> np.ndarray:
        """(M,) bool: the row has a GGX lobe (Principled, or a Glossy BSDF of non-zero colour)."""
        return self.principled | (self.glossy_colour.max(axis=1) > 0.0)

    def arrays(self) -> dict[str, np.ndarray]:
        """Every per-row array by field name (for files and copies)."""
        return {"albedo": self.albedo, **{name: getattr(self, name) for name, *_ in self.PARAMETERS}}

    def __len__(self) -> int:
        return len(self.albedo)


# Kinds of seen light.
SEEN_RECTANGLE, SEEN_ELLIPSE, SEEN_DISK, SEEN_SPHERE, SEEN_SUN = 0, 1, 2, 3, 4


@dataclass
class SeenLights:
    """The lights drawn where the camera sees them.

    Attributes
    ----------
    kind : (N,) int64          SEEN_RECTANGLE, SEEN_ELLIPSE (area lights), SEEN_DISK, SEEN_SPHERE (point and
                               spot lamps), SEEN_SUN.
    centre : (N, 3) float64    an area light's or a lamp's centre (m); a sun's unit direction towards it.
    axes : (N, 2, 3) float64   an area light's half-axes u, v (m): its points are centre + a u + b v with
                               |a|, |b| <= 1 (rectangle) or a^2 + b^2 <= 1 (ellipse); it emits towards u x v.
                               Zeros for the other kinds.
    radius : (N,) float64      a lamp's radius (m), a sun's half-angle (radians); 0 for area lights.
    radiance : (N, 3) float64  W m^-2 sr^-1 per colour channel, before Spread and cone.
    spread : (N,) float64      an area light's Spread (radians; pi: none).
    spot_frame, spot_cos_half, spot_smooth : a spot's cone, as ``scene.FacingLights`` holds it (cos_half
                               below -1: no cone).
    """

    kind: np.ndarray
    centre: np.ndarray
    axes: np.ndarray
    radius: np.ndarray
    radiance: np.ndarray
    spread: np.ndarray
    spot_frame: np.ndarray
    spot_cos_half: np.ndarray
    spot_smooth: np.ndarray

    def __post_init__(self) -> None:
        self.kind = np.asarray(self.kind, np.int64).reshape(-1)
        count = len(self.kind)
        self.centre = np.asarray(self.centre, np.float64).reshape(count, 3)
        self.axes = np.asarray(self.axes, np.float64).reshape(count, 2, 3)
        self.radius = np.asarray(self.radius, np.float64).reshape(count)
        self.radiance = np.asarray(self.radiance, np.float64).reshape(count, 3)
        self.spread = np.asarray(self.spread, np.float64).reshape(count)
        self.spot_frame = np.asarray(self.spot_frame, np.float64).reshape(count, 3, 3)
        self.spot_cos_half = np.asarray(self.spot_cos_half, np.float64).reshape(count)
        self.spot_smooth = np.asarray(self.spot_smooth, np.float64).reshape(count)

    def __len__(self) -> int:
        return len(self.kind)

    @classmethod
    def empty(cls) -> "SeenLights":
        return cls(np.zeros(0, np.int64), np.zeros((0, 3)), np.zeros((0, 2, 3)), np.zeros(0), np.zeros((0, 3)),
                   np.zeros(0), np.zeros((0, 3, 3)), np.zeros(0), np.zeros(0))

    @classmethod
    def area(cls, centre, u, v, radiance, ellipse: bool = False, spread: float = np.pi) -> "SeenLights":
        """One area light: centre (3,), half-axes u, v (3,) with u x v its emitting side, radiance (3,)."""
        return cls([SEEN_ELLIPSE if ellipse else SEEN_RECTANGLE], [centre], [[u, v]], [0.0], [radiance], [spread],
                   [np.eye(3)], [-2.0], [0.0])

    @classmethod
    def lamp(cls, centre, radius: float, intensity, soft_falloff: bool = True, spot=None) -> "SeenLights":
        """One point or spot lamp: centre (3,), radius (m), intensity (3,) W/sr; ``spot`` = (frame (3, 3),
        cos_half, smooth) as ``FacingLights.spot`` stores them, or None."""
        radiance = np.asarray(intensity, np.float64) / (np.pi * radius * radius)
        frame, cos_half, smooth = spot if spot is not None else (np.eye(3), -2.0, 0.0)
        return cls([SEEN_DISK if soft_falloff else SEEN_SPHERE], [centre], np.zeros((1, 2, 3)), [radius], [radiance],
                   [np.pi], [frame], [cos_half], [smooth])

    @classmethod
    def sun(cls, towards, half_angle: float, irradiance) -> "SeenLights":
        """One sun: the direction towards it (3,), its half-angle (radians), irradiance (3,) W/m^2."""
        towards = np.asarray(towards, np.float64)
        radiance = np.asarray(irradiance, np.float64) / (np.pi * np.sin(half_angle) ** 2)
        return cls([SEEN_SUN], [towards / np.linalg.norm(towards)], np.zeros((1, 2, 3)), [half_angle], [radiance],
                   [np.pi], [np.eye(3)], [-2.0], [0.0])

    @classmethod
    def concat(cls, parts: list["SeenLights"]) -> "SeenLights":
        if not parts:
            return cls.empty()
        return cls(*(np.concatenate([getattr(p, name) for p in parts]) for name in SEEN_ARRAYS))

    def subset(self, keep) -> "SeenLights":
        return SeenLights(*(getattr(self, name)[keep] for name in SEEN_ARRAYS))

    def validated(self) -> tuple["SeenLights", int]:
        """These lights without those of non-finite or degenerate values (a ValueError for negative
        radiance); returns them and how many were dropped."""
        if len(self) == 0:
            return self, 0
        if (self.radiance < 0).any():
            raise ValueError("seen lights' radiance must not be negative")
        arrays = [getattr(self, name).reshape(len(self), -1) for name in SEEN_ARRAYS[1:]]
        finite = np.all([np.isfinite(a).all(axis=1) for a in arrays], axis=0)
        doubled = np.linalg.norm(np.cross(self.axes[:, 0], self.axes[:, 1]), axis=1)
        area = self.kind <= SEEN_ELLIPSE
        sized = np.where(area, doubled > 0, (self.radius > 0) & ((self.kind != SEEN_SUN) | (self.radius < 0.5 * np.pi)))
        keep = finite & sized & (self.radiance.max(axis=1) > 0)
        return (self if keep.all() else self.subset(keep)), int((~keep).sum())


SEEN_ARRAYS = ("kind", "centre", "axes", "radius", "radiance", "spread", "spot_frame", "spot_cos_half",
               "spot_smooth")


@dataclass
class Scene:
    """Everything the core renders.

    Attributes
    ----------
    triangles : (T, 3, 3) float64
        World-space triangle vertices.
    material_index : (T,) int64
        Row of ``materials`` for each triangle.
    materials : Materials
    lights : Lights
    camera : Camera
    background : (3,) float64
        Constant background radiance seen where no surface is hit.
    shading_normals : (T, 3, 3) float64 or None
        Optional per-vertex shading normals (smooth shading); None shades with the geometric normal.
    corner_uvs : (T, 3, 2) float64 or None
        Texture coordinates at each triangle corner (Blender's render UV map), needed by textures.
    textures : list[ImageTexture]
        Images that materials' ``texture_index`` refers to.
    terminator_offset : (T,) float64 or None
        Cycles' Shadow Terminator Geometry Offset of each triangle's object (0 to 1; Blender's default
        0.1): shadow rays leaving smooth-shaded triangles near grazing light start from the smooth surface
        the vertex normals describe, lifted off the flat triangle (``terminator.terminator_lift``). None: 0.
    facing : FacingLights
        Point, spot and sun lights (after ``lights`` in the light order of passes and statistics).
    hulls : EmitterHulls
        Mesh emitters grouped as hulls, one light each (after ``facing``); their faces are also triangles of
        the scene (they block other lights), not rows of ``lights``.
    seen : SeenLights
        The lights the camera sees (Ray Visibility > Camera), drawn over the image (``seen_lights``); they
        light nothing as such (their lighting is in ``lights`` and ``facing``).
    """

    triangles: np.ndarray
    material_index: np.ndarray
    materials: Materials
    lights: Lights
    camera: Camera
    background: np.ndarray = field(default_factory=lambda: np.zeros(3))
    shading_normals: np.ndarray | None = None
    corner_uvs: np.ndarray | None = None
    textures: list = field(default_factory=list)
    terminator_offset: np.ndarray | None = None
    facing: FacingLights = field(default_factory=FacingLights.empty)
    hulls: EmitterHulls = field(default_factory=EmitterHulls.empty)
    seen: SeenLights = field(default_factory=SeenLights.empty)

    def __post_init__(self) -> None:
        self.triangles = _as_float_array("triangles", self.triangles, (3, 3)) if len(np.asarray(self.triangles)) \
            else np.zeros((0, 3, 3))
        self.material_index = np.asarray(self.material_index, dtype=np.int64).reshape(-1)
        self.background = np.asarray(self.background, dtype=np.float64).reshape(3)
        if self.shading_normals is not None:
            self.shading_normals = _as_float_array("shading normals", self.shading_normals, (3, 3))
        if self.corner_uvs is not None:
            self.corner_uvs = _as_float_array("corner UVs", self.corner_uvs, (3, 2))
        if self.terminator_offset is not None:
            self.terminator_offset = np.asarray(self.terminator_offset, dtype=np.float64).reshape(-1)

    # -- validation ----------------------------------------------------------------------------------
    def validated(self, progress: Progress | None = None) -> "Scene":
        """A copy fit to render: bad values raise a ValueError naming what is wrong; degenerate triangles
        and lights are dropped with a warning on ``progress``.

        Raises
        ------
        ValueError
            NaN or infinite coordinates, radiance or albedo; negative radiance or albedo; material indices
            out of range; shape mismatches; a non-planar or non-convex light polygon.
        """
        progress = progress or Progress()
        triangles, material_index = self.triangles, self.material_index
        if len(material_index) != len(triangles):
            raise ValueError(f"material_index has {len(material_index)} entries for {len(triangles)} triangles")
        _require_finite("triangle vertices", triangles)
        albedo = np.asarray(self.materials.albedo, dtype=np.float64).reshape(-1, 3)
        emission = self.materials.emission
        _require_finite("material albedos", albedo)
        _require_finite("material emissions", emission)
        if (albedo < 0).any() or (emission < 0).any():
            raise ValueError("material albedos and emissions must not be negative")
        if len(triangles) and (material_index.min() < 0 or material_index.max() >= len(albedo)):
            raise ValueError(f"material_index refers to materials outside 0..{len(albedo) - 1}")
        _require_finite("background colour", self.background[None])
        materials = self.materials
        for name in ("diffuse_weight", "metallic", "roughness", "ior", "specular_level", "specular_tint",
                     "glossy_colour"):
            value = getattr(materials, name)
            _require_finite(f"material {name.replace('_', ' ')}s", value)
            if (value < 0).any():
                raise ValueError(f"material {name.replace('_', ' ')} must not be negative")

        texture_index = self.materials.texture_index
        if (texture_index >= len(self.textures)).any() or (texture_index < -1).any():
            raise ValueError(f"material texture_index refers to textures outside 0..{len(self.textures) - 1}")
        corner_uvs = self.corner_uvs
        if corner_uvs is not None and corner_uvs.shape[0] != len(triangles):
            raise ValueError(f"corner UVs have {corner_uvs.shape[0]} rows for {len(triangles)} triangles")
        if (texture_index >= 0).any() and corner_uvs is None:
            progress.warn("textured materials without UVs show the texture's corner (0, 0) colour")
            corner_uvs = np.zeros((len(triangles), 3, 2))
        shading_normals = self.shading_normals
        if shading_normals is not None:
            if shading_normals.shape != triangles.shape:
                raise ValueError(f"shading normals have shape {shading_normals.shape}, triangles {triangles.shape}")
            _require_finite("shading normals", shading_normals)
        terminator_offset = self.terminator_offset
        if terminator_offset is not None:
            if len(terminator_offset) != len(triangles):
                raise ValueError(f"terminator_offset has {len(terminator_offset)} entries for {len(triangles)} "
                                 "triangles")
            _require_finite("shadow terminator offsets", terminator_offset)
            terminator_offset = np.clip(terminator_offset, 0.0, 1.0)

        # Zero-area triangles can be hit by no ray and block nothing; drop them (scale-relative test).
        cross = np.cross(triangles[:, 1] - triangles[:, 0], triangles[:, 2] - triangles[:, 0])
        doubled_area = np.linalg.norm(cross, axis=1)
        edge_scale = np.max(np.linalg.norm(triangles - np.roll(triangles, 1, axis=1), axis=2), axis=1) \
            if len(triangles) else np.zeros(0)
        degenerate = doubled_area <= 1e-12 * np.maximum(edge_scale ** 2, 1e-300)
        if degenerate.any():
            progress.warn(f"dropped {int(degenerate.sum())} zero-area triangle(s)")
            keep = ~degenerate
            triangles, material_index = triangles[keep], material_index[keep]
            if shading_normals is not None:
                shading_normals = shading_normals[keep]
            if corner_uvs is not None:
                corner_uvs = corner_uvs[keep]
            if terminator_offset is not None:
                terminator_offset = terminator_offset[keep]

        lights = _validated_lights(self.lights, progress)
        if corner_uvs is not None:
            _require_finite("corner UVs", corner_uvs)
        parameters = dict(materials.arrays(), albedo=albedo, emission=emission, texture_index=texture_index)
        if len(albedo) == 0:  # no surfaces (lights only): one black row, so that per-batch lookups stay valid
            parameters = Materials(np.zeros((1, 3))).arrays()
        parameters["metallic"] = np.clip(parameters["metallic"], 0.0, 1.0)
        parameters["roughness"] = np.clip(parameters["roughness"], 0.0, 1.0)
        facing = _validated_facing(self.facing, progress)
        hulls = _validated_hulls(self.hulls, progress)
        seen, dropped = self.seen.validated()
        if dropped:
            progress.warn(f"{dropped} light(s) seen by the camera have a zero size, no power or a NaN transform "
                          "and are not drawn")
        # A camera built well and changed since (a script writing its arrays) is checked again: a NaN
        # transform would otherwise miss everything and show the background, silently (found by fuzzing).
        camera = dataclasses.replace(self.camera)
        return Scene(triangles, material_index, Materials(**parameters), lights, camera,
                     self.background, shading_normals, corner_uvs, list(self.textures), terminator_offset, facing,
                     hulls, seen)

    @property
    def light_count(self) -> int:
        """Polygon lights, facing lights and emitter hulls: the lights of passes and statistics."""
        return len(self.lights) + len(self.facing) + len(self.hulls)

    # -- files ---------------------------------------------------------------------------------------
    def save_npz(self, path) -> None:
        """Write the scene as a .npz archive that ``Scene.load_npz`` and the command line read."""
        camera = self.camera
        arrays = dict(
            triangles=self.triangles, material_index=self.material_index,
            **{("material_" + name if name not in ("albedo", "emission", "texture_index") else name): value
               for name, value in self.materials.arrays().items()},
            light_vertices=self.lights.vertices, light_vertex_count=self.lights.vertex_count,
            light_radiance=self.lights.radiance, light_two_sided=self.lights.two_sided,
            light_cast_shadow=self.lights.cast_shadow, light_spread=self.lights.spread, light_lobes=self.lights.lobes,
            world_from_camera=camera.world_from_camera, resolution=np.array([camera.width, camera.height]),
            projection=np.array(camera.projection), screen_window=camera.screen_window,
            window=np.array(camera.window), clip=np.array([camera.clip_start, camera.clip_end]),
            background=self.background,
        )
        if self.shading_normals is not None:
            arrays["shading_normals"] = self.shading_normals
        if self.corner_uvs is not None:
            arrays["corner_uvs"] = self.corner_uvs
        if self.terminator_offset is not None:
            arrays["terminator_offset"] = self.terminator_offset
        if len(self.facing):
            for name in FACING_ARRAYS:
                arrays["facing_" + name] = getattr(self.facing, name)
        if len(self.seen):
            for name in SEEN_ARRAYS:
                arrays["seen_" + name] = getattr(self.seen, name)
        if len(self.hulls):
            arrays.update(hull_triangles=self.hulls.triangles, hull_index=self.hulls.hull,
                          hull_radiance=self.hulls.radiance, hull_lobes=self.hulls.lobes,
                          hull_convex=self.hulls.convex)
        for index, texture in enumerate(self.textures):
            arrays[f"texture_{index}_texels"] = texture.texels
            arrays[f"texture_{index}_options"] = np.array([str(int(texture.srgb)), texture.interpolation,
                                                          texture.extension])
        np.savez_compressed(path, **arrays)

    @classmethod
    def load_npz(cls, path) -> "Scene":
        """Read a scene written by ``save_npz``; a missing array raises a ValueError naming it."""
        with np.load(path, allow_pickle=False) as data:
            required = ("triangles", "material_index", "albedo", "light_vertices", "light_vertex_count",
                        "light_radiance", "world_from_camera", "resolution", "screen_window")
            missing = [name for name in required if name not in data]
            if missing:
                raise ValueError(f"{path}: not a LazyVis scene, missing arrays {', '.join(missing)}")
            width, height = (int(v) for v in data["resolution"])
            window = tuple(int(v) for v in data["window"]) if "window" in data else None
            clip = data["clip"] if "clip" in data else (0.0, np.inf)
            camera = Camera(data["world_from_camera"], width, height,
                            str(data["projection"]) if "projection" in data else "perspective",
                            data["screen_window"], window, float(clip[0]), float(clip[1]))
            count = len(data["light_vertex_count"])
            lights = Lights(np.array(data["light_vertices"], dtype=np.float64).reshape(count, -1, 3) if count
                            else np.zeros((0, 3, 3)),
                            np.array(data["light_vertex_count"], dtype=np.int64),
                            np.array(data["light_radiance"], dtype=np.float64).reshape(count, 3),
                            np.array(data["light_two_sided"], bool) if "light_two_sided" in data
                            else np.zeros(count, bool),
                            np.array(data["light_cast_shadow"], bool) if "light_cast_shadow" in data else None,
                            np.array(data["light_spread"], np.float64) if "light_spread" in data else None,
                            np.array(data["light_lobes"], np.int64) if "light_lobes" in data else None)
            textures = []
            while f"texture_{len(textures)}_texels" in data:
                srgb, interpolation, extension = (str(v) for v in data[f"texture_{len(textures)}_options"])
                textures.append(ImageTexture(np.array(data[f"texture_{len(textures)}_texels"], dtype=np.float32),
                                             bool(int(srgb)), interpolation, extension))
            return cls(np.array(data["triangles"]), np.array(data["material_index"]),
                       Materials(np.array(data["albedo"], dtype=np.float64).reshape(-1, 3),
                                 np.array(data["emission"]) if "emission" in data else None,
                                 np.array(data["texture_index"]) if "texture_index" in data else None,
                                 **{name: np.array(data["material_" + name])
                                    for name, *_ in Materials.PARAMETERS[2:] if "material_" + name in data}),
                       lights, camera,
                       np.array(data["background"]) if "background" in data else np.zeros(3),
                       np.array(data["shading_normals"]) if "shading_normals" in data else None,
                       np.array(data["corner_uvs"]) if "corner_uvs" in data else None, textures,
                       np.array(data["terminator_offset"]) if "terminator_offset" in data else None,
                       FacingLights(*(np.array(data["facing_" + name]) if "facing_" + name in data else None
                                      for name in FACING_ARRAYS))
                       if "facing_kind" in data else FacingLights.empty(),
                       EmitterHulls(np.array(data["hull_triangles"]), np.array(data["hull_index"]),
                                    np.array(data["hull_radiance"]),
                                    np.array(data["hull_lobes"]) if "hull_lobes" in data else None,
                                    np.array(data["hull_convex"]) if "hull_convex" in data else None)
                       if "hull_radiance" in data else EmitterHulls.empty(),
                       SeenLights(*(np.array(data["seen_" + name]) for name in SEEN_ARRAYS))
                       if "seen_kind" in data else SeenLights.empty())


FACING_ARRAYS = ("kind", "centre", "radius", "intensity", "spot_frame", "spot_cos_half", "spot_smooth",
                 "cast_shadow", "lobes")


def _validated_facing(facing: FacingLights, progress: Progress) -> FacingLights:
    """Check point, spot and sun lights (finite, known kind, radius >= 0, intensity >= 0); drop dark ones and
    suns without a direction with a warning."""
    if len(facing) == 0:
        return facing
    for name in FACING_ARRAYS[1:]:
        _require_finite(f"point/spot/sun light {name.replace('_', ' ')}", np.asarray(getattr(facing, name))[None])
    if not np.isin(facing.kind, list(FACING_KINDS.values())).all():
        raise ValueError(f"facing light kinds must be one of {sorted(FACING_KINDS.values())}")
    if (facing.radius < 0).any() or (facing.intensity < 0).any():
        raise ValueError("point/spot/sun light radius and intensity must not be negative")
    directionless = (facing.kind == FACING_SUN) & ~(np.linalg.norm(facing.centre, axis=1) > 0)
    dark = facing.intensity.max(axis=1) <= 0
    if (dark | directionless).any():
        progress.warn(f"dropped {int((dark | directionless).sum())} point/spot/sun light(s) of zero power or "
                      "without a direction")
    return facing.subset(~(dark | directionless))


def _validated_hulls(hulls: EmitterHulls, progress: Progress) -> EmitterHulls:
    """Check convex emitters (finite faces and radiance, radiance >= 0, face rows in range); drop dark ones."""
    if len(hulls) == 0:
        return hulls
    _require_finite("emitter hull faces", hulls.triangles)
    _require_finite("emitter hull radiance", hulls.radiance)
    if (hulls.radiance < 0).any():
        raise ValueError("emitter hull radiance must not be negative")
    if len(hulls.hull) != len(hulls.triangles) or (hulls.hull < 0).any() or (hulls.hull >= len(hulls)).any():
        raise ValueError("emitter hull faces must name an emitter in 0..H-1")
    if (np.bincount(hulls.hull, minlength=len(hulls))[hulls.convex] < 4).any():
        raise ValueError("a convex emitter hull needs at least 4 faces (a closed convex mesh)")
    dark = hulls.radiance.max(axis=1) <= 0
    if dark.any():
        progress.warn(f"dropped {int(dark.sum())} mesh emitter(s) of zero radiance")
    return hulls.subset(~dark) if dark.any() else hulls


def _validated_lights(lights: Lights, progress: Progress) -> Lights:
    """Check light polygons (finite, planar, convex, non-negative radiance); drop zero-area ones with a warning."""
    count = len(lights)
    if count == 0:
        return lights
    vertices = np.asarray(lights.vertices, dtype=np.float64)
    _require_finite("light vertices", vertices)
    radiance = np.asarray(lights.radiance, dtype=np.float64)
    _require_finite("light radiance", radiance)
    if (radiance < 0).any():
        raise ValueError("light radiance must not be negative")
    vertex_count = np.asarray(lights.vertex_count, dtype=np.int64)
    if (vertex_count < 3).any() or (vertex_count > vertices.shape[1]).any():
        raise ValueError("each light needs between 3 and V vertices")

    # Newell's normal: robust for any planar polygon, length = 2 x area.
    newell = np.zeros((count, 3))
    vmax = vertices.shape[1]
    for k in range(vmax):  # loop over polygon vertices (a handful), arrays over lights
        nxt = (k + 1) % vmax
        newell += np.cross(vertices[:, k], vertices[:, nxt])
    area = 0.5 * np.linalg.norm(newell, axis=1)
    size = np.max(np.linalg.norm(vertices - vertices[:, :1], axis=2), axis=1)
    zero = (area <= 1e-12 * np.maximum(size ** 2, 1e-300)) | (radiance.max(axis=1) <= 0)
    if zero.any():
        names = ", ".join(str(i) for i in np.flatnonzero(zero))
        progress.warn(f"dropped {int(zero.sum())} light(s) with zero area or zero radiance (light {names})")
    keep = ~zero
    vertices, vertex_count, radiance = vertices[keep], vertex_count[keep], radiance[keep]
    normal = newell[keep] / np.maximum(np.linalg.norm(newell[keep], axis=1, keepdims=True), 1e-300)
    size = size[keep]
    # Planarity and convexity, to a tolerance relative to the light's size.
    offsets = np.einsum("lvk,lk->lv", vertices - vertices[:, :1], normal)
    if (np.abs(offsets) > 1e-6 * size[:, None]).any():
        raise ValueError("light polygons must be planar")
    turn = np.einsum("lvk,lk->lv", np.cross(np.roll(vertices, -1, axis=1) - vertices,
                                            np.roll(vertices, -2, axis=1) - np.roll(vertices, -1, axis=1)), normal)
    if (turn < -1e-9 * size[:, None] ** 2).any():
        raise ValueError("light polygons must be convex")
    two_sided = np.asarray(lights.two_sided, bool)[keep]
    spread = np.clip(np.asarray(lights.spread, dtype=np.float64).reshape(-1), 0.0, np.pi)
    return Lights(vertices, vertex_count, radiance, two_sided, np.asarray(lights.cast_shadow, bool)[keep], spread[keep],
                  np.asarray(lights.lobes, np.int64)[keep])
