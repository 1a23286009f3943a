"""Converting cameras between file formats, and measuring what a conversion changes.

A conversion is judged by where the two cameras put the same rays, over the whole image
(`projection_difference`): the viewing rays of a dense grid of pixels of one camera,
borders and corners included, are projected with the other, in both directions, and the
pixel differences summarised. A conversion that keeps the lens model exactly differs by
~1e-9 px (the undistortion's round-off); anything above `EXACT_PX` is not a lossless copy.

A file format that cannot hold a camera (formats.py has the limits: COLMAP and mrcal have
no skew, COLMAP takes at most 8 opencv coefficients, mrcal 12 and no fisheye) is met in two
ways (`convert_camera`): terms that the format cannot hold are dropped when that moves no
pixel of the image by more than `EXACT_PX`; otherwise the conversion is refused, or, when
asked to approximate, the nearest model the format holds is fitted to the source's
projection (`fit_model`: least squares over a grid of rays covering the image).

Whether a format holds a camera is asked of its writer (`round_trip` writes to a temporary
file and reads it back), so the limits have one home, formats.py.

Example
-------
>>> from pencilcal.toolkit.camera.model import Camera
>>> K = [[800.0, 0, 319.5], [0, 800.0, 239.5], [0, 0, 1]]
>>> cam = Camera("opencv", 640, 480, K, [-0.2, 0.05, 0.001, -0.001, 0.01])
>>> conv = convert_camera(cam, "cameras.txt")      # nothing is written to that path
>>> conv.fitted, conv.stored == cam, conv.difference.max_px < 1e-6
(False, True, True)
"""
from __future__ import annotations

import tempfile
from dataclasses import dataclass
from pathlib import Path
from typing import NamedTuple

import numpy as np

from pencilcal.toolkit.camera.formats import camera_format, read_camera, write_camera
from pencilcal.toolkit.camera.model import OPENCV_COEFFICIENT_COUNTS, Camera
from pencilcal.toolkit.errors import InputError

__all__ = [
    "EXACT_PX",
    "GRID_STEP_PX",
    "FIT_GRID_POINTS",
    "ProjectionDifference",
    "Conversion",
    "describe_camera",
    "pixel_grid",
    "projection_difference",
    "round_trip",
    "representable",
    "nearest_model",
    "truncate_model",
    "fit_model",
    "convert_camera",
]

#: Largest reprojection difference over the image [px] that still counts as an exact copy.
EXACT_PX = 0.01
#: Spacing of the pixel grid on which `projection_difference` compares two cameras [px].
GRID_STEP_PX = 16.0
#: Grid points along the longer image side on which `fit_model` fits.
FIT_GRID_POINTS = 48

# Temporary file names by format: a name of the format is all a writer looks at.
_FORMAT_NAMES = {"json": "camera.json", "filestorage": "camera.yaml", "cameramodel": "camera.cameramodel",
                 "colmap_txt": "cameras.txt", "colmap_bin": "cameras.bin", "colmap_folder": "model"}
# A residual [px] standing in for a projection that fails (NaN, a model the optimiser left)
_FAILED_RESIDUAL_PX = 1e6
# Least-squares evaluations allowed per fitted parameter, and the radii at which a
# rational denominator is checked for a pole
_MAX_NFEV_PER_PARAMETER = 200
_POLE_SAMPLES = 1024


class ProjectionDifference(NamedTuple):
    """Where two cameras put the same rays apart, over the image [px].

    max_px: the largest difference (inf where one camera sees a ray the other does not
    project, or a pixel the other does not unproject); rms_px: the RMS difference;
    pixels: grid pixels compared (both directions together).
    """

    max_px: float
    rms_px: float
    pixels: int


@dataclass(frozen=True)
class Conversion:
    """A camera as a file format holds it (`convert_camera`).

    camera: what to write; stored: that camera as the format reads it back; difference:
    source vs stored over the image; fitted: whether `camera` was fitted (approximate);
    reason: why the format could not hold the source as it is ("" when it could).
    """

    camera: Camera
    stored: Camera
    difference: ProjectionDifference
    fitted: bool
    reason: str


def describe_camera(camera: Camera) -> str:
    """A short name of the lens model: ``"pinhole"``, ``"fisheye"``, ``"opencv with 5 coefficients"``.

    >>> describe_camera(Camera("pinhole", 4, 3, [[2.0, 0, 1.5], [0, 2.0, 1.0], [0, 0, 1]]))
    'pinhole'
    """
    if camera.model == "opencv":
        return f"opencv with {camera.dist.size} coefficients"
    if camera.spline is not None:
        c = camera.spline
        return f"splined stereographic ({c.Nx} x {c.Ny} knots over {c.fov_x_deg} deg)"
    return camera.model


def pixel_grid(width, height, step_px=GRID_STEP_PX):
    """A grid of pixels covering the whole image, its outer border and corners included.

    width, height: image size [px]; step_px: the largest spacing [px]. The image spans
    [-0.5, width - 0.5] x [-0.5, height - 0.5] (pixel (0, 0) is the centre of the top-left
    pixel). Returns (N, 2) pixels, rows along x first.

    >>> pixel_grid(4, 2, step_px=2.0).tolist()
    [[-0.5, -0.5], [1.5, -0.5], [3.5, -0.5], [-0.5, 1.5], [1.5, 1.5], [3.5, 1.5]]
    """
    if not step_px > 0:
        raise InputError(f"grid step must be positive, got {step_px!r}")
    u = np.linspace(-0.5, width - 0.5, int(np.ceil(width / step_px)) + 1)
    v = np.linspace(-0.5, height - 0.5, int(np.ceil(height / step_px)) + 1)
    return np.stack(np.meshgrid(u, v), -1).reshape(-1, 2)


def projection_difference(cam_a: Camera, cam_b: Camera, step_px=GRID_STEP_PX) -> ProjectionDifference:
    """How far apart two cameras of one image size project the same rays, over the image.

    The pixels of a grid covering the image (`pixel_grid`, borders and corners included)
    are unprojected to rays by one camera and projected with the other, both ways round.
    `cam_a` is the reference: the pixels it unprojects are the image compared (a lens
    model may fold back before the corners); a pixel there that `cam_b` does not
    unproject, or a ray one camera sees and the other cannot project, counts as inf.

    Parameters
    ----------
    cam_a, cam_b : Camera
        Same width and height; typically the source and the converted camera.
    step_px : float
        Grid spacing [px].

    Returns
    -------
    ProjectionDifference
        ``(max_px, rms_px, pixels)`` [px].

    Example
    -------
    >>> K = [[800.0, 0, 319.5], [0, 800.0, 239.5], [0, 0, 1]]
    >>> a = Camera("opencv", 640, 480, K, [-0.2, 0.05, 0.0, 0.0])
    >>> b = Camera("opencv", 640, 480, K, [-0.2, 0.05, 0.0, 0.0, 0.0])
    >>> projection_difference(a, b).max_px < 1e-6
    True
    >>> round(projection_difference(a, Camera("pinhole", 640, 480, K)).max_px, 1)
    21.8
    """
    if cam_a.size != cam_b.size:
        raise InputError(f"cameras of different image sizes {cam_a.size} and {cam_b.size} cannot be compared")
    px = pixel_grid(cam_a.width, cam_a.height, step_px)
    rays_a = cam_a.rays_from_pixels(px)
    seen = np.all(np.isfinite(rays_a), axis=-1)
    if not np.any(seen):
        raise InputError("the reference camera unprojects no pixel of its image")
    px, rays_a = px[seen], rays_a[seen]
    rays_b = cam_b.rays_from_pixels(px)
    with np.errstate(invalid="ignore", over="ignore"):
        err = np.concatenate([np.linalg.norm(cam_b.project(rays_a) - px, axis=-1),
                              np.linalg.norm(cam_a.project(rays_b) - px, axis=-1)])
        err = np.where(np.isfinite(err), err, np.inf)
        rms = float(np.sqrt(np.mean(err * err)))
    return ProjectionDifference(float(err.max()), rms, int(err.size))


def _reason(e: InputError, path: Path) -> str:
    """A writer's message without the temporary path it names."""
    return str(e).removeprefix(f"{path}: ")


def round_trip(camera: Camera, path) -> Camera:
    """The camera as the file format of `path` holds it: written to a temporary file of
    that format and read back. `path` only names the format; nothing is written there.

    Raises InputError with the writer's reason (no path) when the format cannot hold it.

    >>> cam = Camera("opencv", 640, 480, [[500.0, 0, 319.5], [0, 500.0, 239.5], [0, 0, 1]], [0.1, 0, 0, 0, 0, 0, 0, 0])
    >>> describe_camera(round_trip(cam, "cameras.bin"))     # FULL_OPENCV, k4..k6 zero
    'opencv with 5 coefficients'
    """
    name = _FORMAT_NAMES[camera_format(path)]
    with tempfile.TemporaryDirectory(prefix="pencilcal-convert-") as tmp:
        p = Path(tmp) / name
        try:
            write_camera(p, camera)
        except InputError as e:
            raise InputError(_reason(e, p)) from None
        return read_camera(p)


def representable(camera: Camera, path) -> tuple[bool, str]:
    """Whether the file format of `path` holds `camera` exactly, and if not, why.

    Exactly: the writer takes it and the camera read back projects within `EXACT_PX` of
    it over the whole image. `path` only names the format; nothing is written there.

    >>> cam = Camera("opencv", 640, 480, [[500.0, 0, 319.5], [0, 500.0, 239.5], [0, 0, 1]], [0.0] * 12)
    >>> representable(cam, "cam.cameramodel")
    (True, '')
    >>> representable(cam, "cameras.txt")[1]
    'COLMAP has no camera model for 12 opencv coefficients (thin prism / sensor tilt); it takes 4, 5 or 8'
    """
    try:
        stored = round_trip(camera, path)
    except InputError as e:
        return False, str(e)
    diff = projection_difference(camera, stored)
    if not diff.max_px <= EXACT_PX:
        return False, f"it reads back {diff.max_px:.3g} px apart"
    return True, ""


def _accepts(path, model, count, skew, size) -> bool:
    """Whether the format of `path` takes a (zero-distortion) camera of this model."""
    K = [[1000.0, 1.0 if skew else 0.0, size[0] / 2], [0.0, 1000.0, size[1] / 2], [0.0, 0.0, 1.0]]
    try:
        round_trip(Camera(model, size[0], size[1], K, np.zeros(count)), path)
    except InputError:
        return False
    return True


def nearest_model(camera: Camera, path) -> tuple[str, int, bool]:
    """The lens model closest to `camera`'s that the format of `path` takes.

    Returns (model, coefficients, skew): the same model with as many of its coefficients
    as the format holds (opencv's nest: 4 within 5 within 8, 12, 14), a fisheye as
    opencv with the most coefficients where the format has no fisheye, and skew only
    where the format holds it. Raises InputError if the format takes no camera like it.

    >>> cam = Camera("opencv", 640, 480, [[500.0, 0, 319.5], [0, 500.0, 239.5], [0, 0, 1]], [0.0] * 14)
    >>> nearest_model(cam, "cameras.txt"), nearest_model(cam, "cam.cameramodel")
    (('opencv', 8, False), ('opencv', 12, False))
    """
    skew = camera.skew != 0 and _accepts(path, camera.model, camera.dist.size, True, camera.size)
    n = camera.dist.size
    opencv = [("opencv", c) for c in sorted(OPENCV_COEFFICIENT_COUNTS, reverse=True)]
    if camera.model == "opencv":
        candidates = [m for m in opencv if m[1] <= n] + [("pinhole", 0)]
    elif camera.model == "fisheye":
        candidates = [("fisheye", n)] + opencv + [("pinhole", 0)]
    elif camera.spline is not None:
        candidates = opencv + [("fisheye", 4), ("pinhole", 0)]
    else:
        candidates = [("pinhole", 0)]
    for model, count in candidates:
        if _accepts(path, model, count, skew, camera.size):
            return model, count, skew
    raise InputError(f"{path}: holds no camera model close to {describe_camera(camera)}")


def truncate_model(camera: Camera, model: str, coefficients: int, skew=False) -> Camera:
    """`camera` with only what a (model, coefficients) camera holds: the first
    `coefficients` of its distortion (zero-padded) for the same model, no distortion for
    another, and K[0,1] = 0 unless `skew`. The start of `fit_model`; no meta.

    >>> cam = Camera("opencv", 640, 480, [[500.0, 0, 319.5], [0, 500.0, 239.5], [0, 0, 1]], [0.1, 0.2, 0, 0, 0.3])
    >>> truncate_model(cam, "opencv", 4).dist.tolist()
    [0.1, 0.2, 0.0, 0.0]
    """
    dist = np.zeros(coefficients)
    if model == camera.model:
        keep = min(coefficients, camera.dist.size)
        dist[:keep] = camera.dist[:keep]
    K = np.array(camera.K)
    if not skew:
        K[0, 1] = 0.0
    return Camera(model, camera.width, camera.height, K, dist)


def _camera_from_params(template: Camera, params, skew) -> Camera:
    fx, fy, cx, cy = params[:4]
    s = params[4] if skew else 0.0
    dist = params[5:] if skew else params[4:]
    return Camera(template.model, template.width, template.height, [[fx, s, cx], [0.0, fy, cy], [0.0, 0.0, 1.0]],
                  dist)


def _fit_rays(camera: Camera, model: str):
    """The rays (N, 3) `camera` sees on the fit grid and their pixels (N, 2)."""
    px = pixel_grid(camera.width, camera.height, max(camera.size) / FIT_GRID_POINTS)
    rays = camera.rays_from_pixels(px)
    seen = np.all(np.isfinite(rays), axis=-1)
    px, rays = px[seen], rays[seen]
    if len(px) < FIT_GRID_POINTS:
        raise InputError("the camera unprojects too few pixels of its image to fit another model")
    if model != "fisheye" and rays[:, 2].min() <= 0:
        widest = float(np.degrees(np.arccos(np.clip(rays[:, 2].min(), -1.0, 1.0))))
        raise InputError(f"the image reaches {widest:.1f} deg off the axis, where the {model} model "
                         "cannot project (it ends at 90 deg)")
    return rays, px


def _least_squares(start: Camera, rays, px, skew) -> Camera:
    """`start`'s model fitted to project `rays` (N, 3) to `px` (N, 2), from `start`."""
    from scipy.optimize import least_squares

    x0 = np.r_[start.fx, start.fy, start.cx, start.cy, [start.skew] if skew else [], start.dist]

    def residuals(params):
        try:
            fitted = _camera_from_params(start, params, skew)
        except InputError:  # fx or fy <= 0, a tilt beyond 90 deg
            return np.full(px.size, _FAILED_RESIDUAL_PX)
        with np.errstate(all="ignore"):
            r = (fitted.project(rays) - px).ravel()
        return np.where(np.isfinite(r), r, _FAILED_RESIDUAL_PX)

    res = least_squares(residuals, x0, x_scale="jac", method="lm", max_nfev=_MAX_NFEV_PER_PARAMETER * x0.size)
    return _camera_from_params(start, res.x, skew)


def _pole_free(camera: Camera, r2_max) -> bool:
    """Whether the rational term's denominator 1 + k4 r^2 + k5 r^4 + k6 r^6 of an opencv
    camera stays positive for r^2 in [0, r2_max] (always true for the other models)."""
    if camera.model != "opencv" or camera.dist.size < 8:
        return True
    k4, k5, k6 = camera.dist[5:8]
    r2 = np.linspace(0.0, r2_max, _POLE_SAMPLES)
    return bool(np.all(1.0 + r2 * (k4 + r2 * (k5 + r2 * k6)) > 0))


def _padded(camera: Camera, coefficients) -> Camera:
    dist = np.zeros(coefficients)
    dist[: camera.dist.size] = camera.dist
    return Camera(camera.model, camera.width, camera.height, camera.K, dist)


def fit_model(camera: Camera, model: str, coefficients: int, skew=False) -> Camera:
    """The (model, coefficients) camera that projects like `camera` over its whole image.

    Least squares (scipy.optimize.least_squares) over the rays `camera` sees on a grid
    of ``FIT_GRID_POINTS`` pixels along the longer side, borders and corners included:
    the pixel residuals of fx, fy, cx, cy (the skew too when `skew`) and the distortion
    coefficients, started from `truncate_model`. Rational terms that nearly cancel can
    buy a lower RMS with a pole inside the image: an opencv fit whose denominator
    1 + k4 r^2 + k5 r^4 + k6 r^6 vanishes there is dropped for a fit with the next
    smaller coefficient count (14, 12, 8, 5, 4; the rest zero). Of that fit and the
    truncated camera, the one with the smaller largest `projection_difference` wins.

    Parameters
    ----------
    camera : Camera
        The source.
    model : {"pinhole", "opencv", "fisheye"}
    coefficients : int
        Distortion coefficients of the result (0 for pinhole).
    skew : bool
        Fit K[0,1] too; else it is 0.

    Returns
    -------
    Camera
        Same image size; no meta (the source's calibration statistics describe its own
        parameters).

    Raises
    ------
    InputError
        If `camera` sees rays the model cannot project (beyond 90 deg for opencv).

    Example
    -------
    >>> K = [[800.0, 0, 319.5], [0, 800.0, 239.5], [0, 0, 1]]
    >>> cam = Camera("opencv", 640, 480, K, [-0.2, 0.05, 0.0, 0.0, 0.02])
    >>> fit = fit_model(cam, "opencv", 4)
    >>> d = projection_difference(cam, fit)
    >>> bool(d.max_px < 0.05 < projection_difference(cam, truncate_model(cam, "opencv", 4)).max_px)
    True
    """
    rays, px = _fit_rays(camera, model)
    r2_max = float(np.max(np.sum((rays[:, :2] / rays[:, 2:]) ** 2, axis=-1)))
    counts = [c for c in OPENCV_COEFFICIENT_COUNTS if c <= coefficients] if model == "opencv" else []
    candidates = [truncate_model(camera, model, coefficients, skew)] if model == camera.model else []
    for count in sorted(counts, reverse=True) or [coefficients]:
        fit = _padded(_least_squares(truncate_model(camera, model, count, skew), rays, px, skew), coefficients)
        if _pole_free(fit, r2_max):
            candidates.append(fit)
            break
    candidates = [c for c in candidates if _pole_free(c, r2_max)]
    if not candidates:
        raise InputError(f"every {model} fit has a pole inside the image")
    return min(candidates, key=lambda c: projection_difference(camera, c).max_px)


def _refusal(path, why, start, drop, target_fit):
    """The one-line message for a camera the format of `path` cannot hold within EXACT_PX;
    `drop` is the difference `start` (the source truncated) makes, None across models."""
    if drop is not None:
        lost = (f"; as {describe_camera(start)} it would differ by up to {drop.max_px:.3g} px over the image "
                f"(over {EXACT_PX:g} px)")
    else:
        lost = ""
    try:
        fit = target_fit()
        offer = (f"--approximate writes the best-fitting {describe_camera(fit.stored)} "
                 f"(max {fit.difference.max_px:.3g} px, RMS {fit.difference.rms_px:.3g} px over the image)")
    except InputError as e:
        offer = f"and no {describe_camera(start)} approximates it: {e}"
    return f"{path}: {why}{lost}; {offer}"


def convert_camera(camera: Camera, path, approximate=False) -> Conversion:
    """The camera to write to `path` (format by extension) for `camera`; nothing is written.

    The format holds the camera as it is, or without terms that move no pixel by more
    than `EXACT_PX`; or, with `approximate`, the nearest model it holds is fitted
    (`fit_model`). The difference is measured on the camera as the format reads it back.

    Raises
    ------
    InputError
        ``"<path>: <what the format cannot hold>; <the difference it would cause>; ..."``
        when the format cannot hold the camera within EXACT_PX and not `approximate`.
    """
    camera_format(path)  # an unknown extension is an error of its own, not a limit of a format
    try:
        stored = round_trip(camera, path)
    except InputError as e:
        why = str(e)
    else:
        diff = projection_difference(camera, stored)
        if diff.max_px <= EXACT_PX:
            return Conversion(camera, stored, diff, False, "")
        why = f"it reads back {diff.max_px:.3g} px apart"
    model, count, skew = nearest_model(camera, path)
    if (model, count, skew) == (camera.model, camera.dist.size, camera.skew != 0):
        raise InputError(f"{path}: {why}")  # not the lens model: nothing to fit
    start = truncate_model(camera, model, count, skew)

    def target_fit():
        fitted = fit_model(camera, model, count, skew)
        kept = round_trip(fitted, path)
        return Conversion(fitted, kept, projection_difference(camera, kept), True, why)

    drop = None
    if model == camera.model:
        kept = round_trip(start, path)
        drop = projection_difference(camera, kept)
        if drop.max_px <= EXACT_PX:
            return Conversion(start, kept, drop, False, why)
    if not approximate:
        raise InputError(_refusal(path, why, start, drop, target_fit))
    try:
        return target_fit()
    except InputError as e:
        raise InputError(f"{path}: {why}; no {describe_camera(start)} approximates it: {e}") from None
