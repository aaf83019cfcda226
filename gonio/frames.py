"""Camera frames: checks, masks, dark subtraction, exposure brackets, auto-exposure, the sample's mean
radiance with its uncertainty, and EXR files with metadata and a content hash.

A frame is a float HDR image (H, W, 3) in signal units (what the sensor read, black level included)
with a metadata dict (pose in °, ``exposure_s``, ``black_level``, ``saturation``, ...). Rates are
(signal − black level − dark) / exposure_s: for a linear sensor, radiance in the detector's units.

Sample region. :func:`find_sample_region` thresholds the luminance at Otsu's level (scikit-image),
keeps the largest connected component, fills its holes and erodes it by ``erode_px`` pixels
(:func:`erode_disk`), so that the pixels along the patch's edge (partly sample, partly surround) are left
out.

Brackets. :func:`merge_brackets` averages the rates of the exposures with hat weights
w = min(x, 1 − x) of the normalized reading x = (v − black)/(saturation − black): readings near the
middle of the range are trusted most, those near the noise floor or the clip little, saturated ones
not at all (a small floor weight keeps dark pixels, which no exposure lifts off the floor).

Uncertainty. :func:`region_mean` takes the mean rate over the region's pixels per channel, and its
standard error σ/√n from the per-pixel noise σ, estimated from the differences of horizontally adjacent
pixels, σ² = mean((x[i, j+1] − x[i, j])²)/2: a smooth radiance gradient across the patch (a real
property of the scene, not noise) cancels in the differences to first order, independent pixel noise
(sensor, or the renderer's Monte Carlo) does not.
"""

from __future__ import annotations

import hashlib
import json
import math
import os
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

__all__ = ["Frame", "FrameError", "check_frame", "saturation_mask", "subtract_dark", "find_sample_region",
           "erode_disk", "merge_brackets", "auto_exposure", "region_mean", "content_hash", "write_exr",
           "read_exr"]

#: Weight of an unsaturated reading at the very ends of the range (relative to 0.5 at mid-range).
_FLOOR_WEIGHT = 1e-3


class FrameError(ValueError):
    """A frame that cannot be used: the message is one line naming the frame and what is wrong."""


@dataclass(frozen=True)
class Frame:
    """A camera frame: ``pixels`` (H, W, 3) float32 in signal units, and its ``metadata``."""

    pixels: np.ndarray
    metadata: dict = field(default_factory=dict)


def check_frame(pixels, *, shape: tuple[int, int] | None = None, saturation: float = math.inf,
                name: str = "frame") -> np.ndarray:
    """``pixels`` as a float array (H, W, 3), or FrameError for a wrong size, NaN or all saturated.

    Parameters
    ----------
    pixels : array_like
        The frame.
    shape : (H, W), optional
        The size it must have.
    saturation : float
        Full-scale reading: a frame whose every pixel reaches it in some channel is refused.
    name : str
        What the messages call the frame.
    """
    px = np.asarray(pixels)
    if px.ndim != 3 or px.shape[2] != 3 or 0 in px.shape:
        raise FrameError(f"{name}: expected an image of shape (H, W, 3), got shape {px.shape}")
    if shape is not None and px.shape[:2] != tuple(shape):
        raise FrameError(f"{name}: expected {shape[1]}x{shape[0]} pixels (W x H), "
                         f"got {px.shape[1]}x{px.shape[0]}")
    if not np.issubdtype(px.dtype, np.floating):
        px = px.astype(np.float64)
    bad = ~np.isfinite(px).all(axis=2)
    if bad.any():
        r, c = np.argwhere(bad)[0]
        raise FrameError(f"{name}: {int(bad.sum())} pixel(s) are NaN or infinite "
                         f"(first at row {r}, column {c})")
    if saturation_mask(px, saturation).all():
        raise FrameError(f"{name}: every pixel is saturated (>= {saturation:g}); shorten the exposure")
    return px


def saturation_mask(pixels, saturation: float) -> np.ndarray:
    """Pixels (H, W) with a channel at or above the full-scale reading ``saturation``."""
    return (np.asarray(pixels) >= saturation).any(axis=-1)


def subtract_dark(pixels, dark, *, name: str = "frame") -> np.ndarray:
    """``pixels − dark``: a dark frame of the same shape and exposure, or one value per channel."""
    px = np.asarray(pixels, dtype=np.float64)
    d = np.asarray(dark, dtype=np.float64)
    if d.ndim == 3 and d.shape != px.shape:
        raise FrameError(f"{name}: the dark frame has shape {d.shape}, the frame {px.shape}")
    if d.ndim == 3:
        check_frame(d, name=f"{name} dark")
    return px - d


def find_sample_region(pixels, *, erode_px: int = 2, name: str = "frame") -> np.ndarray:
    """The sample's pixels (H, W, bool): the largest bright component, holes filled, edges eroded.

    Parameters
    ----------
    pixels : array_like (H, W, 3)
        A frame (the black level may be left in: only contrast matters).
    erode_px : int
        Pixels removed from the region's border (the partly covered edge pixels), >= 0.

    Raises
    ------
    FrameError
        If the frame has no contrast, or nothing is left after the erosion.
    """
    from scipy import ndimage
    from skimage import filters, measure

    px = check_frame(pixels, name=name)
    lum = px.mean(axis=2)
    if float(lum.max() - lum.min()) <= 0.0:
        raise FrameError(f"{name}: no contrast; the sample region cannot be found (give it instead)")
    bright = lum > filters.threshold_otsu(lum)
    labels = measure.label(bright, connectivity=1)
    sizes = np.bincount(labels.ravel())
    sizes[0] = 0
    region = ndimage.binary_fill_holes(labels == int(np.argmax(sizes)))
    if erode_px > 0:
        region = erode_disk(region, int(erode_px))
    if not region.any():
        raise FrameError(f"{name}: the sample region is empty after eroding {erode_px} px")
    return region


def erode_disk(mask, radius: int) -> np.ndarray:
    """``mask`` (H, W, bool) eroded by a disk of ``radius`` pixels: a pixel stays where every pixel
    within the disk ((dy, dx) with dy² + dx² <= radius²) around it is set, the frame's border mirrored
    (the edge pixel repeated). What ``skimage.morphology.erosion(mask, skimage.morphology.disk(radius))``
    returns (checked against it in tests/test_frames.py), without importing scikit-image's morphology
    (and through it scipy.spatial: half a second of CPU at the start of a simulated camera's campaign).
    """
    mask = np.asarray(mask, dtype=bool)
    r = int(radius)
    if r < 0:
        raise ValueError(f"radius: must be >= 0 pixels, got {radius!r}")
    if r == 0:
        return mask.copy()
    h, w = mask.shape
    padded = np.pad(mask, r, mode="symmetric")
    out = np.ones((h, w), dtype=bool)
    for dy in range(-r, r + 1):
        reach = math.isqrt(r * r - dy * dy)
        rows = padded[r + dy:r + dy + h]
        for dx in range(-reach, reach + 1):
            out &= rows[:, r + dx:r + dx + w]
    return out


def merge_brackets(frames, exposures_s, *, saturation: float, black_level: float = 0.0, dark=None,
                   ) -> tuple[np.ndarray, np.ndarray]:
    """One HDR rate image from an exposure bracket.

    Parameters
    ----------
    frames : sequence of array_like (H, W, 3)
        Readings (signal units, black level included), one per exposure.
    exposures_s : sequence of float
        Their exposures (s), > 0.
    saturation, black_level : float
        Full-scale reading and the sensor's offset (signal units).
    dark : array_like, optional
        A dark rate (signal units per s, (H, W, 3) or per channel) to subtract.

    Returns
    -------
    rate : ndarray (H, W, 3)
        Σ w (v − black)/t / Σ w with the hat weights of the module docstring; NaN where every
        exposure saturated that channel.
    valid : ndarray (H, W), bool
        Pixels with a rate in every channel.
    """
    exposures = [float(t) for t in exposures_s]
    if len(frames) != len(exposures) or not frames:
        raise FrameError(f"brackets: {len(frames)} frame(s) for {len(exposures)} exposure(s)")
    if any(not t > 0.0 for t in exposures):
        raise FrameError(f"brackets: exposures must be > 0 s, got {exposures}")
    span = saturation - black_level
    num = den = None
    shape = None
    for j, (f, t) in enumerate(zip(frames, exposures, strict=True)):
        # Size and finiteness only: the longest exposure of a bracket may well be all saturated.
        px = check_frame(np.asarray(f, dtype=np.float64), shape=shape, name=f"bracket {j} ({t:g} s)")
        shape = px.shape[:2]
        x = (px - black_level) / span
        w = np.where(px >= saturation, 0.0, np.maximum(np.minimum(x, 1.0 - x), _FLOOR_WEIGHT))
        r = (px - black_level) / t
        num = w * r if num is None else num + w * r
        den = w if den is None else den + w
    with np.errstate(invalid="ignore", divide="ignore"):
        rate = np.where(den > 0.0, num / den, np.nan)
    if dark is not None:
        rate = rate - np.asarray(dark, dtype=np.float64)
    valid = np.isfinite(rate).all(axis=2)
    if not valid.any():
        raise FrameError(f"brackets: every pixel is saturated in every exposure "
                         f"(shortest {min(exposures):g} s)")
    return rate, valid


def auto_exposure(pixels, exposure_s: float, *, saturation: float, black_level: float = 0.0, mask=None,
                  target: float = 0.5, percentile: float = 99.0,
                  limits_s: tuple[float, float] = (1e-6, 3600.0)) -> float:
    """The exposure (s) for the next reading: the region's ``percentile`` brightest channel value at
    ``target`` of the sensor's range.

    Parameters
    ----------
    pixels : array_like (H, W, 3)
        The last frame (signal units, black level included), taken at ``exposure_s``.
    saturation, black_level : float
        Full-scale reading and offset (signal units).
    mask : array_like (H, W) of bool, optional
        The pixels that matter (the sample region); default all.
    target : float
        Fraction of the range (saturation − black) to aim for, in (0, 1).
    percentile : float
        Which brightness to place at the target, in (0, 100].
    limits_s : (float, float)
        Allowed exposures (s): the result is kept inside.

    Returns
    -------
    float
        The next exposure (s). If more than (100 − percentile) % of the region is saturated the
        brightness is unknown: a quarter of ``exposure_s``.
    """
    px = np.asarray(pixels, dtype=np.float64)
    if px.ndim != 3 or px.shape[2] != 3:
        raise FrameError(f"frame: expected an image of shape (H, W, 3), got shape {px.shape}")
    if not 0.0 < target < 1.0:
        raise ValueError(f"target: must be in (0, 1), got {target!r}")
    m = np.ones(px.shape[:2], bool) if mask is None else np.asarray(mask, bool)
    vals = px[m]
    if vals.size == 0:
        raise FrameError("frame: the mask selects no pixel")
    span = saturation - black_level
    sat_fraction = float((vals >= saturation).any(axis=1).mean())
    if sat_fraction > (100.0 - percentile) / 100.0:
        new = exposure_s / 4.0
    else:
        level = float(np.percentile((vals - black_level).max(axis=1), percentile))
        new = exposure_s * 16.0 if level <= 0.0 else exposure_s * target * span / level
        new = min(new, exposure_s * 16.0)  # a frame near the noise floor says little: grow by steps
    return float(np.clip(new, *limits_s))


def region_mean(pixels, mask, *, exposure_s: float = 1.0, black_level: float = 0.0,
                saturation: float = math.inf) -> tuple[np.ndarray, np.ndarray, int]:
    """Mean rate per channel over a region, its standard error, and the pixels used.

    Parameters
    ----------
    pixels : array_like (H, W, 3)
        A frame in signal units (black level included), or a merged rate image with
        ``exposure_s=1`` and ``black_level=0``. NaN pixels (a merge's invalid ones) are left out.
    mask : array_like (H, W) of bool
        The region.
    exposure_s, black_level, saturation : float
        To turn readings into rates, and to leave out saturated pixels.

    Returns
    -------
    mean : ndarray (3,)
        Mean of (v − black)/exposure_s over the region's usable pixels.
    stderr : ndarray (3,)
        σ/√n, σ² from adjacent-pixel differences (module docstring).
    n : int
        Usable pixels.
    """
    px = np.asarray(pixels, dtype=np.float64)
    m = np.asarray(mask, bool)
    if px.ndim != 3 or px.shape[2] != 3 or m.shape != px.shape[:2]:
        raise FrameError(f"frame: expected (H, W, 3) pixels and an (H, W) mask, got {px.shape} and {m.shape}")
    use = m & np.isfinite(px).all(axis=2) & ~saturation_mask(px, saturation)
    n = int(use.sum())
    if n < 2:
        raise FrameError(f"frame: {n} usable pixel(s) in the region (saturated or masked out)")
    rate = (px - black_level) / float(exposure_s)
    mean = rate[use].mean(axis=0)
    pair = use[:, 1:] & use[:, :-1]
    if pair.sum() >= 2:
        diff = (rate[:, 1:] - rate[:, :-1])[pair]
        sigma = np.sqrt(np.mean(diff * diff, axis=0) / 2.0)
    else:
        sigma = rate[use].std(axis=0, ddof=1)
    return mean, sigma / math.sqrt(n), n


# -- EXR ---------------------------------------------------------------------------------------------
def content_hash(pixels) -> str:
    """SHA-256 (hex) of the pixels as little-endian float32, shape included."""
    px = np.ascontiguousarray(np.asarray(pixels, dtype="<f4"))
    h = hashlib.sha256(repr(px.shape).encode())
    h.update(px.tobytes())
    return h.hexdigest()


def write_exr(path, frame: Frame) -> str:
    """Write a frame to an OpenEXR file (float32 R, G, B) with its metadata and content hash.

    The metadata goes in as JSON in the header attribute ``gonio:metadata``, the hash of the pixels
    (:func:`content_hash`) in ``gonio:sha256``. The file appears whole or not at all (written aside
    and renamed). Returns the hash.
    """
    import OpenImageIO as oiio

    path = Path(path)
    px = check_frame(frame.pixels, name=str(path)).astype(np.float32)
    digest = content_hash(px)
    h, w, _ = px.shape
    spec = oiio.ImageSpec(w, h, 3, oiio.FLOAT)
    spec.channelnames = ("R", "G", "B")
    spec.attribute("compression", "zip")
    spec.attribute("gonio:metadata", json.dumps(frame.metadata, sort_keys=True, default=_json_default))
    spec.attribute("gonio:sha256", digest)
    tmp = path.with_name(f".{path.stem}.{os.getpid()}.partial{path.suffix}")
    out = oiio.ImageOutput.create(str(tmp))
    try:
        if out is None or not out.open(str(tmp), spec) or not out.write_image(px):
            raise FrameError(f"{path}: cannot write EXR ({oiio.geterror() or 'unknown error'})")
        out.close()
        os.replace(tmp, path)
    finally:
        tmp.unlink(missing_ok=True)
    return digest


def read_exr(path) -> Frame:
    """Read a frame written by :func:`write_exr`; FrameError if unreadable or the hash disagrees."""
    import OpenImageIO as oiio

    inp = oiio.ImageInput.open(str(path))
    if inp is None:
        raise FrameError(f"{path}: cannot read EXR ({oiio.geterror() or 'unknown error'})")
    try:
        spec = inp.spec()
        px = np.asarray(inp.read_image(0, 0, 0, 3, "float"), dtype=np.float32)
    finally:
        inp.close()
    meta_text = spec.get_string_attribute("gonio:metadata", "")
    digest = spec.get_string_attribute("gonio:sha256", "")
    if not digest:
        raise FrameError(f"{path}: no gonio:sha256 attribute (not written by gonio.frames.write_exr)")
    if content_hash(px) != digest:
        raise FrameError(f"{path}: content hash mismatch: the pixels are not those written")
    return Frame(px, json.loads(meta_text) if meta_text else {})


def _json_default(value):
    if isinstance(value, np.generic):
        return value.item()
    if isinstance(value, np.ndarray):
        return value.tolist()
    raise TypeError(f"metadata: {type(value).__name__} is not JSON serializable")
