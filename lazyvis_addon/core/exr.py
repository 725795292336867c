"""Multi-channel OpenEXR files through the OpenEXR 3.x Python binding.

Images are numpy arrays of shape (H, W) with row 0 the top row (the EXR convention: the first scanline of
the data window is the top of the image), one array per named channel ("R", "G", "B", "A", "Depth",
"Normal.X", ...). Files are single-part scanline images with ZIP compression.
"""

from __future__ import annotations

import os

import numpy as np


def write_exr(path, channels: dict[str, np.ndarray], half: bool = False, attributes: dict[str, str] | None = None
              ) -> None:
    """Write named (H, W) channels to a scanline EXR file with ZIP compression.

    Parameters
    ----------
    path : str or os.PathLike
        Output file; overwritten if it exists.
    channels : dict[str, (H, W) array]
        Channel name -> pixel values (any real dtype; row 0 is the top row). Names are used as given;
        EXR stores channels sorted by name, so ``read_exr`` returns them in that order.
    half : bool
        Store 16-bit half floats instead of 32-bit floats (values beyond +-65504 become +-inf).
    attributes : dict[str, str] or None
        Extra string attributes for the header (metadata such as Blender's "Note" or "Frame").

    Raises
    ------
    ValueError
        No channels, a bad channel name, an array that is not 2-D or empty, or channels of different shapes.
    """
    import OpenEXR

    if not channels:
        raise ValueError("write_exr needs at least one channel, got an empty dict")
    pixel_dtype = np.float16 if half else np.float32
    pixels_by_name: dict[str, np.ndarray] = {}
    shape = None
    for name, values in channels.items():
        if not isinstance(name, str) or not name:
            raise ValueError(f"EXR channel names must be non-empty strings, got {name!r}")
        array = np.asarray(values)
        if array.ndim != 2 or array.size == 0:
            raise ValueError(f"EXR channel {name!r} must be a non-empty 2-D (H, W) array, got shape {array.shape}")
        if shape is None:
            shape, first_name = array.shape, name
        elif array.shape != shape:
            raise ValueError(f"EXR channels must all have one shape: {first_name!r} is {shape[0]} x {shape[1]} "
                             f"(H x W) but {name!r} is {array.shape[0]} x {array.shape[1]}")
        # C order matters: the binding writes the raw buffer, so a Fortran-ordered array comes out scrambled.
        with np.errstate(over="ignore"):  # out-of-range values become +-inf, as documented
            pixels_by_name[name] = np.ascontiguousarray(array, dtype=pixel_dtype)
    # The binding fills in and replaces entries of both dicts it is given: hand it fresh ones every time.
    header = {"compression": OpenEXR.ZIP_COMPRESSION, "type": OpenEXR.scanlineimage}
    for key, value in (attributes or {}).items():
        if not isinstance(key, str) or not isinstance(value, str) or key in header:
            raise ValueError(f"EXR attributes must be new string keys with string values, got {key!r}: {value!r}")
        header[key] = value
    with OpenEXR.File(header, dict(pixels_by_name)) as exr_file:
        exr_file.write(os.fspath(path))


def read_exr(path) -> dict[str, np.ndarray]:
    """Read every channel of the first part of an EXR file.

    Parameters
    ----------
    path : str or os.PathLike

    Returns
    -------
    dict[str, (H, W) float32]
        Channel name -> pixels (row 0 is the top row), in the file's channel order (sorted by name).
        Half and uint channels are converted to float32.

    Raises
    ------
    ValueError
        Subsampled channels (their arrays would not all be H x W).
    """
    import OpenEXR

    with OpenEXR.File(os.fspath(path), separate_channels=True) as exr_file:
        channels = {name: np.array(channel.pixels, dtype=np.float32)  # a copy owned by numpy
                    for name, channel in exr_file.channels().items()}
    shapes = {array.shape for array in channels.values()}
    if len(shapes) > 1 or any(len(s) != 2 for s in shapes):
        listed = ", ".join(f"{name}: {array.shape}" for name, array in channels.items())
        raise ValueError(f"{os.fspath(path)}: channels are not all H x W images ({listed})")
    return channels


def read_exr_parts(path) -> list[tuple[str, dict[str, str], dict[str, np.ndarray]]]:
    """Every part of an EXR file (Blender's multilayer EXR puts each pass in a part of its own): a list of
    (part name, its string attributes, {channel name: (H, W) float32}), in the file's order."""
    import OpenEXR

    parts = []
    with OpenEXR.File(os.fspath(path), separate_channels=True) as exr_file:
        for part in exr_file.parts:  # parts: one per pass, a handful
            attributes = {key: value for key, value in part.header.items() if isinstance(value, str)}
            channels = {name: np.array(channel.pixels, dtype=np.float32) for name, channel in part.channels.items()}
            parts.append((part.name(), attributes, channels))
    return parts


def write_exr_parts(path, parts: list[tuple[str, dict[str, str], dict[str, np.ndarray]]]) -> None:
    """Write ``read_exr_parts``' list back as 32-bit float scanline parts with ZIP compression: a single-part
    file for one unnamed part, a multi-part file otherwise (each part keeps its name and string attributes;
    all channels of one part must share one (H, W) shape)."""
    import OpenEXR

    if len(parts) == 1 and not parts[0][0]:
        name, attributes, channels = parts[0]
        write_exr(path, channels, attributes={k: v for k, v in attributes.items() if k not in ("name", "type")})
        return
    built = []
    for name, attributes, channels in parts:  # parts: a handful
        header = {"compression": OpenEXR.ZIP_COMPRESSION, "type": OpenEXR.scanlineimage}
        header.update({key: value for key, value in attributes.items() if key not in ("name", "type")})
        built.append(OpenEXR.Part(header, {channel: np.ascontiguousarray(values, dtype=np.float32)
                                           for channel, values in channels.items()}, name))
    with OpenEXR.File(built) as exr_file:
        exr_file.write(os.fspath(path))
