"""Synthetic scenarios with exact truth: orbit, pivot and tilt-sweep.

A `Scenario` holds a camera, the printed `Sheet`, a `Backdrop` and, per frame, the exact
pose of the sheet and everything derived from it. Poses come without images, so tests can
use them directly; `Scenario.render(i)` draws frame i (render.py) when an image is wanted.

Scenarios
---------
``orbit``
    The camera moves around the static sheet on a smooth path (azimuth sweeping 150 deg,
    20-37 deg off the sheet's normal, 340-460 mm away for the default 1280x720 camera with
    f = 1000 px), always looking at the printed area, over a textured table with boxes:
    overlapping views with 40-65 deg of viewpoint change, for structure from motion.
``pivot``
    A fixed camera sees the sheet and an instrument shaft pivoting about a fulcrum in a
    plane parallel to the sheet, a few millimetres above it; one known pivot angle per
    frame. The shaft's axis passes through the fulcrum, so the image lines of its axis all
    pass through the fulcrum's image (``vertex_px``).
``tilt-sweep``
    A fixed camera; the sheet turns about an in-plane axis through the fan's vertex from
    0 to 80 deg of tilt (the chapter's experiment). The vertex stays put (on the optical
    axis by default) and the fan is in view in every frame.

Truth, per frame (frames.py conventions; lengths in mm): ``image``,
``R_cam_from_target``, ``t_cam_from_target``, ``normal`` (= R[:, 2], pointing away from
the camera), ``vertex_px`` (the fan's vertex; the fulcrum for pivot) and ``vertex_cam``,
``tilt_deg`` (angle between the normal and the vertex's viewing ray), ``camera_center``
(in the target frame), ``spokes_px`` (raw pixel end points of every spoke's centre line,
inner to outer), ``board_corners_in_view``; plus ``axis_deg`` (tilt-sweep) or
``angle_deg``, ``fulcrum_cam`` (the 3-D fulcrum), ``shaft_direction_cam`` (from the fulcrum
towards the tip), the frame's 3-D axis as `pencil.cylinder` gives it (``axis_point_cam``, its
point closest to the camera centre, and ``axis_direction_cam``, unit with z >= 0), ``tip_px``,
``shaft_edges_normalized`` (pivot).

Example
-------
>>> sc = make_scenario("tilt-sweep", frames=5, seed=0, size=(640, 360))
>>> [round(f["tilt_deg"], 6) for f in sc.frames]
[0.0, 20.0, 40.0, 60.0, 80.0]
>>> sc.render(2).shape
(360, 640)
"""
from __future__ import annotations

import math
from dataclasses import dataclass, field
from types import MappingProxyType

import numpy as np

from pencilcal.toolkit.camera.model import Camera
from pencilcal.toolkit.errors import InputError
from pencilcal.toolkit.geometry.frames import angle_between, rotation_about_axis, rotation_to_z
from pencilcal.toolkit.pencil.spec import project_spokes
from pencilcal.toolkit.synth.objects import Backdrop, Instrument
from pencilcal.toolkit.synth.render import render_frame
from pencilcal.toolkit.synth.sheet import Sheet, layout_sheet

__all__ = ["SCENARIOS", "RENDER_DEFAULTS", "Scenario", "make_scenario", "default_camera", "look_at", "image_names"]

SCENARIOS = ("orbit", "pivot", "tilt-sweep", "handheld")

#: What a real camera adds, used by `Scenario.render` (and `pencilcal simulate`).
RENDER_DEFAULTS = MappingProxyType({"noise": 2.0, "blur_px": 0.6, "lighting": 0.25, "gamma": 2.2})

# the options each scenario takes (make_scenario's **options)
_OPTIONS = MappingProxyType({
    "orbit": frozenset({"distance", "azimuth_span_deg", "elevation_deg"}),
    "pivot": frozenset({"distance", "tilt_deg", "angle_range_deg", "shaft_radius", "fulcrum", "height", "tip",
                        "back", "port_view", "epochs", "epoch_move_deg"}),
    "tilt-sweep": frozenset({"distance", "axis_deg", "max_tilt_deg", "vertex_px"}),
    "handheld": frozenset({"distance", "tilt_deg", "speed", "speed_px", "roll_deg", "tilt_rate_deg"}),
})


def default_camera(model="opencv", size=(1280, 720)):
    """A realistic camera: f = 1000 px at 1280 px wide (65 deg across), principal point a
    few pixels off centre, mild barrel distortion; a wide fisheye with f = 500 px.

    Parameters
    ----------
    model : {"opencv", "fisheye", "pinhole"}
    size : (2,) int
        (width, height) [pixels]; the focal length scales with the width.

    Example
    -------
    >>> cam = default_camera("opencv", (1280, 720))
    >>> cam.fx, cam.dist.tolist()
    (1000.0, [-0.12, 0.06, 0.0004, -0.0003, -0.012])
    """
    W, H = (int(v) for v in size)
    if W < 16 or H < 16:
        raise InputError(f"image size must be at least 16x16 pixels, got {W}x{H}")
    s = W / 1280.0
    cx, cy = (W - 1) / 2.0 + 3.2 * s, (H - 1) / 2.0 - 2.1 * s
    if model == "fisheye":
        f = 500.0 * s
        return Camera("fisheye", W, H, [[f, 0, cx], [0, f * 1.0005, cy], [0, 0, 1]], [0.03, -0.01, 0.002, -0.0005])
    f = 1000.0 * s
    K = [[f, 0, cx], [0, f * 1.0005, cy], [0, 0, 1]]
    if model == "opencv":
        return Camera("opencv", W, H, K, [-0.12, 0.06, 0.0004, -0.0003, -0.012])
    if model == "pinhole":
        return Camera("pinhole", W, H, K)
    raise InputError(f"unknown camera model {model!r}; expected opencv, fisheye or pinhole")


def look_at(eye, target, down_hint=(0.0, 1.0, 0.0), roll=0.0):
    """Pose of a camera at `eye` looking at `target` (both target frame [mm]).

    The image's down direction follows `down_hint` (target frame) as far as it can, then
    turns by `roll` [rad] about the optical axis. Returns (R_cam_from_target, t).

    Example
    -------
    >>> R, t = look_at([0.0, 0.0, -100.0], [0.0, 0.0, 0.0])
    >>> R.round(12).tolist(), t.tolist()
    ([[1.0, 0.0, 0.0], [0.0, 1.0, 0.0], [0.0, 0.0, 1.0]], [0.0, 0.0, 100.0])
    """
    eye, target = np.asarray(eye, float), np.asarray(target, float)
    z = target - eye
    z /= np.linalg.norm(z)
    y = np.asarray(down_hint, float) - np.dot(down_hint, z) * z
    if np.linalg.norm(y) < 1e-9:
        raise InputError("look_at: the down hint is parallel to the viewing direction")
    y /= np.linalg.norm(y)
    x = np.cross(y, z)
    c, s = math.cos(roll), math.sin(roll)
    x, y = c * x + s * y, -s * x + c * y
    R = np.stack([x, y, z])
    return R, -R @ eye


def image_names(n):
    """File names 000.png, 001.png, ... (more digits beyond 1000 frames)."""
    width = max(3, len(str(max(n - 1, 0))))
    return [f"{i:0{width}d}.png" for i in range(n)]


@dataclass
class Scenario:
    """A synthetic sequence with exact truth.

    Attributes
    ----------
    name : str
        "orbit", "pivot" or "tilt-sweep".
    camera : Camera
    sheet : Sheet
    backdrop : Backdrop
    frames : list of dict
        Per-frame truth (module docstring); arrays are numpy.
    seed : int
    options : dict
        The scenario's parameters as used (defaults filled in).
    instruments : list of Instrument or None
        Per frame (pivot only).
    extra : dict
        Scenario-level truth (pivot: the pivot plane and fulcrum).
    """

    name: str
    camera: Camera
    sheet: Sheet
    backdrop: Backdrop
    frames: list
    seed: int
    options: dict = field(default_factory=dict)
    instruments: list | None = None
    extra: dict = field(default_factory=dict)

    def __len__(self):
        return len(self.frames)

    def render(self, i, *, noise=None, blur_px=None, lighting=None, gamma=None, color=False, background=None,
               scene=None):
        """Image of frame i, uint8 (H, W) or (H, W, 3) with ``color``.

        Unset options take `RENDER_DEFAULTS` (noise 2 grey levels, blur 0.6 px, lighting
        0.25, gamma 2.2). The noise and lighting of frame i are seeded by (seed, i), so a
        frame renders identically whatever the order. ``background`` overrides the
        scenario's backdrop ("plain", a grey level, or a Backdrop), or is "tissue": a
        tissue-like image behind the instrument instead of the sheet (`tissue.tissue_image`,
        seeded by the seed and the frame's camera epoch: it stays while the camera does).
        ``scene``: the frame's `render.render_scene`, when the sequence shares one (a fixed
        camera: pivot); it replaces the backdrop.
        """
        fr = self.frames[i]
        d = dict(RENDER_DEFAULTS)
        for k, v in (("noise", noise), ("blur_px", blur_px), ("lighting", lighting), ("gamma", gamma)):
            if v is not None:
                d[k] = v
        if isinstance(background, str) and background == "tissue":
            from pencilcal.toolkit.synth.tissue import tissue_image

            background = tissue_image((self.camera.height, self.camera.width), (self.seed, fr.get("epoch", 0)),
                                      color=color)
        rng = np.random.default_rng([int(self.seed), 1, int(i)])
        return render_frame(self.camera, fr["R_cam_from_target"], fr["t_cam_from_target"], self.sheet,
                            instrument=None if self.instruments is None else self.instruments[i],
                            background=self.backdrop if background is None else background,
                            color=color, rng=rng, scene=scene, **d)

    def instrument_coverage(self, i):
        """(H, W) float: the fraction of each pixel the instrument of frame i covers, exact for
        the camera's lens model as `render` draws it (its true segmentation mask: >= 0.5);
        zeros where no instrument shows (InputError for a scenario without instruments)."""
        if self.instruments is None:
            raise InputError(f"the {self.name} scenario has no instrument")
        from pencilcal.toolkit.synth.raster import render_coverage

        fr = self.frames[i]
        outline = self.instruments[i].outline(fr["R_cam_from_target"], fr["t_cam_from_target"])
        if outline is None:
            return np.zeros((self.camera.height, self.camera.width))
        return np.clip(render_coverage(self.camera, [(outline, 1)]), 0.0, 1.0)

    def truth(self, render=None):
        """The truth file's content (JSON-ready: lists and floats)."""
        from pencilcal.toolkit.camera.formats import camera_to_dict
        from pencilcal.toolkit.io.files import to_jsonable

        out = {
            "scenario": self.name,
            "seed": self.seed,
            "frames_count": len(self.frames),
            "conventions": ("OpenCV camera frame (x right, y down, z forward); p_cam = R_cam_from_target p_target + "
                            "t_cam_from_target; target = board frame (x right, y down the sheet, z into it), mm; "
                            "pixel (0, 0) is the centre of the top-left pixel; normal = R[:, 2]; angles in degrees"),
            "camera": camera_to_dict(self.camera),
            "board": self.sheet.board.to_dict(),
            "pencil": self.sheet.pencil.to_dict(),
            "sheet": self.sheet.to_dict(),
            "backdrop": self.backdrop.to_dict(),
            "options": self.options,
        }
        if render is not None:
            out["render"] = render
        out.update(self.extra)
        out["frames"] = self.frames
        return to_jsonable(out)

    def angles_csv(self):
        """``image,angle_deg`` lines for the pivot scenario (None for the others)."""
        if self.name != "pivot":
            return None
        lines = ["image,angle_deg"] + [f"{f['image']},{f['angle_deg']!r}" for f in self.frames]
        return "\n".join(lines) + "\n"


def _distance_scale(camera):
    """Distances that keep the sheet the same size in the image as the default camera."""
    return (camera.K[0, 0] / camera.width) / (1000.0 / 1280.0)


def _content_points(sheet):
    """(N, 3) points that must be seen: the board's corners and every bar's corners."""
    bw, bh = sheet.board.size
    pts = [np.array([[0, 0], [bw, 0], [bw, bh], [0, bh]], float)] + list(sheet.bars)
    p = np.concatenate(pts)
    return np.concatenate([p, np.zeros((len(p), 1))], 1)


def _in_view(camera, R, t, pts, margin):
    """True if target points pts (N, 3) [mm] project at least `margin` px inside the image."""
    px = camera.project(pts @ R.T + t)
    return bool(np.all(np.isfinite(px)) and np.all(px[:, 0] >= margin) and np.all(px[:, 1] >= margin)
                and np.all(px[:, 0] <= camera.width - 1 - margin) and np.all(px[:, 1] <= camera.height - 1 - margin))


def _frame_truth(camera, sheet, R, t, name):
    """The truth every scenario writes for one frame."""
    R = np.asarray(R, float)
    t = np.asarray(t, float)
    v = sheet.pencil.vertex
    V = R @ np.array([v[0], v[1], 0.0]) + t
    obj = sheet.board.object_points() @ R.T + t
    px = camera.project(obj)
    in_view = np.all(np.isfinite(px), axis=1) & (px[:, 0] >= -0.5) & (px[:, 1] >= -0.5) \
        & (px[:, 0] <= camera.width - 0.5) & (px[:, 1] <= camera.height - 0.5)
    return {
        "image": name,
        "R_cam_from_target": R,
        "t_cam_from_target": t,
        "normal": R[:, 2].copy(),
        "vertex_px": camera.project(V),
        "vertex_cam": V,
        "tilt_deg": float(np.degrees(angle_between(R[:, 2], V))),
        "camera_center": -R.T @ t,
        "spokes_px": project_spokes(camera, R, t, sheet.pencil),
        "board_corners_in_view": int(in_view.sum()),
    }


def _option(options, key, default):
    """options[key], or `default` where it is missing or None."""
    v = options.get(key)
    return default if v is None else v


def make_scenario(name, frames, seed=0, camera=None, sheet=None, size=(1280, 720), model="opencv", **options):
    """Build a scenario's poses and truth (no images: see `Scenario.render`).

    Parameters
    ----------
    name : {"orbit", "pivot", "tilt-sweep"}
    frames : int
        Number of frames (>= 1).
    seed : int
        Seeds the path, the backdrop and every frame's noise.
    camera : Camera, optional
        Default: `default_camera(model, size)`.
    sheet : Sheet, optional
        Default: `render.layout_sheet()` (A4 landscape, 7x5 ChArUco, 8 spokes).
    size : (2,) int
        (width, height) of the default camera [pixels].
    model : {"opencv", "fisheye", "pinhole"}
        Lens model of the default camera.
    **options
        orbit: ``distance`` [mm] (mean; default 400 scaled to the camera's field of view),
        ``azimuth_span_deg`` (150), ``elevation_deg`` ((20, 37), off the normal).
        pivot: ``distance`` (380), ``tilt_deg`` (35, of the camera against the sheet),
        ``angle_range_deg`` ((50, 130)), ``shaft_radius`` (2.5), ``fulcrum`` (x, y in the
        target frame; default the fan's vertex), ``height`` (radius + 2: the pivot plane
        is z = -height, parallel to the sheet), ``tip`` (60) and ``back`` (300) [mm];
        ``port_view`` [mm] (None: the camera sees the sheet and the fulcrum): the camera
        looks from this distance, ``tilt_deg`` off the pivot plane's normal, at the shafts'
        middle 0.7 ``tip`` from the fulcrum, as an endoscope sees an instrument whose entry
        port lies outside its view (the sheet far behind, when ``height`` is large);
        ``epochs`` (1): the frames split evenly into this many runs, the camera moved
        between them (turned by ``epoch_move_deg``, 4, about a random axis across its view,
        about a point 100 mm behind it: an endoscope moved about its own port), so that
        the fulcrum's image moves; each frame's truth says its ``epoch``, and the
        scenario's ``epochs`` each one's frames and fulcrum image.
        tilt-sweep: ``axis_deg`` (0: the tilt axis's direction in the sheet, from the
        target x axis), ``max_tilt_deg`` (80), ``distance`` (400), ``vertex_px`` (where
        the vertex is seen; default the principal point, i.e. on the optical axis).

    Returns
    -------
    Scenario

    Raises
    ------
    InputError
        Unknown scenario or option, fewer than one frame, or a pose the camera cannot see.

    Example
    -------
    >>> sc = make_scenario("orbit", frames=4, seed=1, size=(640, 360))
    >>> len(sc), sc.frames[0]["image"], sc.frames[0]["board_corners_in_view"]
    (4, '000.png', 24)
    """
    if name not in SCENARIOS:
        raise InputError(f"unknown scenario {name!r}; expected one of {', '.join(SCENARIOS)}")
    if isinstance(frames, bool) or not isinstance(frames, (int, np.integer)) or frames < 1:
        raise InputError(f"frames must be a positive integer, got {frames!r}")
    unknown = sorted(set(options) - _OPTIONS[name])
    if unknown:
        raise InputError(f"scenario {name}: unknown option(s) {unknown}; expected {sorted(_OPTIONS[name])}")
    seed = int(seed)
    camera = default_camera(model, size) if camera is None else camera
    sheet = layout_sheet() if sheet is None else sheet
    # boxes give structure from motion depth off the plane; only the orbit needs them, and
    # in the fixed-camera scenarios they could hide the shaft or, at grazing tilt, the fan
    backdrop = Backdrop.around(sheet, seed=seed, boxes=6 if name == "orbit" else 0)
    build = {"orbit": _orbit, "pivot": _pivot, "tilt-sweep": _tilt_sweep, "handheld": _handheld}[name]
    return build(camera, sheet, backdrop, int(frames), seed, options)


def _orbit(camera, sheet, backdrop, n, seed, options):
    """The orbit scenario of `n` frames (make_scenario's options for "orbit")."""
    rng = np.random.default_rng([seed, 2])
    scale = _distance_scale(camera)
    D = float(_option(options, "distance", 400.0 * scale))
    span = math.radians(float(_option(options, "azimuth_span_deg", 150.0)))
    el_lo, el_hi = (float(v) for v in _option(options, "elevation_deg", (20.0, 37.0)))
    if not (0.0 <= el_lo <= el_hi < 80.0) or D <= 0:
        raise InputError("orbit: elevation_deg must be 0 <= low <= high < 80 and distance positive")
    centre = sheet.content_center
    az0 = math.pi / 2 + rng.uniform(-0.3, 0.3)  # start on the sheet's +y side (its bottom edge)
    ph = rng.uniform(0.0, 2 * math.pi, 6)
    pts = _content_points(sheet)
    s = np.linspace(0.0, 1.0, n) if n > 1 else np.array([0.5])
    az = az0 + span * (s - 0.5)
    el = np.radians(el_lo + (el_hi - el_lo) * (0.5 + 0.5 * np.sin(2 * np.pi * s + ph[0])))
    dist = D * (1.0 + 0.15 * np.sin(2 * np.pi * 0.8 * s + ph[1]))
    look = centre + 12.0 * np.stack([np.sin(2 * np.pi * s + ph[2]), np.cos(2 * np.pi * s + ph[3]), 0 * s], -1)
    roll = np.radians(4.0 * np.sin(2 * np.pi * 1.1 * s + ph[4]))

    def pose(k, m):
        u = np.array([np.sin(el[k]) * np.cos(az[k]), np.sin(el[k]) * np.sin(az[k]), -np.cos(el[k])])
        return look_at(look[k] + m * dist[k] * u, look[k], (0.0, 1.0, 0.0), roll[k])

    # back off where the printed area would leave the image, smoothly along the path
    need = np.ones(n)
    for k in range(n):
        m = 1.0
        while m < 2.5 and not _in_view(camera, *pose(k, m), pts, 15.0):
            m += 0.02
        need[k] = m
    if n > 2:
        from scipy.ndimage import gaussian_filter1d

        smooth = gaussian_filter1d(need, sigma=max(1.0, n / 15.0), mode="nearest")
        need = smooth * np.max(need / smooth)
    names = _names(n)
    out = []
    for k in range(n):
        R, t = pose(k, need[k])
        out.append(_frame_truth(camera, sheet, R, t, names[k]))
    opts = {"distance": D, "azimuth_span_deg": math.degrees(span), "elevation_deg": [el_lo, el_hi]}
    return Scenario("orbit", camera, sheet, backdrop, out, seed, opts)


def _names(n):
    """`image_names(n)`."""
    return image_names(n)


def _pivot(camera, sheet, backdrop, n, seed, options):
    """The pivot scenario of `n` frames (make_scenario's options for "pivot")."""
    rng = np.random.default_rng([seed, 3])
    scale = _distance_scale(camera)
    D = float(_option(options, "distance", 380.0 * scale))
    tilt = math.radians(float(_option(options, "tilt_deg", 35.0)))
    a0, a1 = (float(v) for v in _option(options, "angle_range_deg", (50.0, 130.0)))
    radius = float(_option(options, "shaft_radius", 2.5))
    fxy = np.asarray(_option(options, "fulcrum", sheet.pencil.vertex), float).reshape(2)
    height = float(_option(options, "height", radius + 2.0))
    tip = float(_option(options, "tip", 60.0))
    back = float(_option(options, "back", 300.0))
    if not (radius > 0 and height >= radius and 0 <= tilt < math.radians(80) and D > 0):
        raise InputError("pivot: needs shaft_radius > 0, height >= shaft_radius, 0 <= tilt_deg < 80, distance > 0")
    fulcrum = np.array([fxy[0], fxy[1], -height])
    az = math.pi / 2 + rng.uniform(-0.5, 0.5)
    u = np.array([math.sin(tilt) * math.cos(az), math.sin(tilt) * math.sin(az), -math.cos(tilt)])
    port_view = options.get("port_view")
    if port_view is not None:
        if not (float(port_view) > radius):
            raise InputError("pivot: port_view must be a distance [mm] beyond the shaft radius")
        mid = math.radians(0.5 * (a0 + a1))
        target = fulcrum + 0.7 * tip * np.array([math.cos(mid), math.sin(mid), 0.0])
        m, D = 1.0, float(port_view)
    else:
        # the camera looks at the middle of the printed area and the fulcrum
        target = (sheet.content_center + np.array([fxy[0], fxy[1], 0.0])) / 2.0
        pts = np.concatenate([_content_points(sheet), fulcrum[None]])
        m = 1.0
        while m < 2.5 and not _in_view(camera, *look_at(target + m * D * u, target), pts, 15.0):
            m += 0.02
    R, t = look_at(target + m * D * u, target, (0.0, 1.0, 0.0), rng.uniform(-0.05, 0.05))
    angles = np.linspace(a0, a1, n) if n > 1 else np.array([(a0 + a1) / 2.0])
    names = _names(n)
    frames, instruments = [], []
    n_ep = int(_option(options, "epochs", 1))
    if not 1 <= n_ep <= n:
        raise InputError(f"pivot: epochs must be between 1 and the number of frames ({n}), got {n_ep}")
    poses = _epoch_poses(R, t, n_ep, float(_option(options, "epoch_move_deg", 4.0)), rng)
    epoch_of = np.minimum((np.arange(n) * n_ep) // max(n, 1), n_ep - 1)
    epochs = [{"epoch": e, "first": int(np.flatnonzero(epoch_of == e)[0]), "last": int(np.flatnonzero(epoch_of == e)[-1]),
               "R_cam_from_target": poses[e][0], "t_cam_from_target": poses[e][1],
               "fulcrum_cam": poses[e][0] @ fulcrum + poses[e][1],
               "fulcrum_px": camera.project(poses[e][0] @ fulcrum + poses[e][1])} for e in range(n_ep)]
    R0, t0 = R, t
    for k, ang in enumerate(angles):
        R, t = poses[int(epoch_of[k])]
        F_cam = R @ fulcrum + t
        ins = Instrument.in_plane(fxy, height, ang, radius=radius, tip=tip, back=back)
        fr = _frame_truth(camera, sheet, R, t, names[k])
        fr["epoch"] = int(epoch_of[k])
        _, a_cam = ins.axis_cam(R, t)
        closest = F_cam - np.dot(F_cam, a_cam) * a_cam
        fr.update({
            "vertex_px": camera.project(F_cam),
            "vertex_cam": F_cam,
            "tilt_deg": float(np.degrees(angle_between(R[:, 2], F_cam))),
            "angle_deg": float(ang),
            "fulcrum_cam": F_cam,
            "shaft_direction_cam": a_cam,
            "axis_point_cam": closest,
            "axis_direction_cam": a_cam if a_cam[2] >= 0 else -a_cam,
            "tip_px": camera.project(F_cam + tip * a_cam),
            "shaft_edges_normalized": _edge_lines(ins.silhouette_planes(R, t)),
        })
        frames.append(fr)
        instruments.append(ins)
    R, t = R0, t0
    F_cam = R @ fulcrum + t
    opts = {"distance": D * m, "tilt_deg": math.degrees(tilt), "angle_range_deg": [a0, a1], "shaft_radius": radius,
            "fulcrum": fxy.tolist(), "height": height, "tip": tip, "back": back, "port_view": port_view,
            "shaft_diameter": 2.0 * radius, "epochs": n_ep, "epoch_move_deg": float(_option(options, "epoch_move_deg",
                                                                                               4.0))}
    extra = {"epochs": epochs, "pivot": {
        "fulcrum_target": fulcrum,
        "fulcrum_cam": F_cam,
        "fulcrum_px": camera.project(F_cam),
        "normal": R[:, 2].copy(),
        "R_cam_from_pivot": R,
        "t_cam_from_pivot": F_cam,
        "note": ("the pivot plane is z = -height in the target frame (parallel to the sheet, towards the camera); "
                 "angle_deg is the shaft direction from the fulcrum towards the tip, from the target x axis "
                 "towards +y, so the pivot frame is the target frame moved to the fulcrum"),
    }}
    return Scenario("pivot", camera, sheet, backdrop, frames, seed, opts, instruments, extra)


def _epoch_poses(R, t, n, move_deg, rng):
    """[(R, t)] of n camera epochs: the first the given pose, each next one the previous turned
    by move_deg [deg] about a random axis across the view, about the point 100 mm behind
    the camera (an endoscope moved about its port)."""
    poses = [(R, t)]
    for _ in range(n - 1):
        Rp, tp = poses[-1]
        C = -Rp.T @ tp
        P = C - 100.0 * Rp[2]  # Rp[2]: the viewing direction in the target frame
        a = rng.uniform(0, 2 * np.pi)
        axis = np.cos(a) * Rp[0] + np.sin(a) * Rp[1]
        Q = rotation_about_axis(axis, math.radians(move_deg))
        C2 = P + Q @ (C - P)
        R2 = Rp @ Q.T
        poses.append((R2, -R2 @ C2))
    return poses


def _edge_lines(m):
    """Silhouette planes (2, 3) -> image lines (a, b, c) in normalised coordinates,
    a x + b y + c = 0 with (a, b) a unit vector."""
    lines = np.asarray(m, float).copy()
    return lines / np.linalg.norm(lines[:, :2], axis=1, keepdims=True)


def _tilt_sweep(camera, sheet, backdrop, n, seed, options):
    """The tilt-sweep scenario of `n` frames (make_scenario's options for "tilt-sweep")."""
    scale = _distance_scale(camera)
    D = float(_option(options, "distance", 400.0 * scale))
    axis_deg = float(_option(options, "axis_deg", 0.0))
    max_tilt = float(_option(options, "max_tilt_deg", 80.0))
    if not (0.0 <= max_tilt < 90.0) or D <= 0:
        raise InputError("tilt-sweep: max_tilt_deg must be in [0, 90) and distance positive")
    vpx = options.get("vertex_px")
    vpx = camera.K[:2, 2].copy() if vpx is None else np.asarray(vpx, float).reshape(2)
    ray = camera.rays_from_pixels(vpx)
    if not np.all(np.isfinite(ray)):
        raise InputError(f"tilt-sweep: vertex_px {vpx.tolist()} is outside the lens model's valid field of view")
    V = ray * D
    R0 = rotation_to_z(ray).T  # frontal: the sheet's normal along the vertex's ray
    a = math.radians(axis_deg)
    axis_t = np.array([math.cos(a), math.sin(a), 0.0])
    v = sheet.pencil.vertex
    vt = np.array([v[0], v[1], 0.0])
    tilts = np.linspace(0.0, max_tilt, n) if n > 1 else np.array([max_tilt])
    names = _names(n)
    frames = []
    for k, g in enumerate(tilts):
        R = R0 @ rotation_about_axis(axis_t, math.radians(g))
        t = V - R @ vt
        fr = _frame_truth(camera, sheet, R, t, names[k])
        fr["tilt_deg"] = float(g)  # exact by construction (the computed value agrees to ~1e-13)
        fr["axis_deg"] = axis_deg
        frames.append(fr)
    opts = {"distance": D, "axis_deg": axis_deg, "max_tilt_deg": max_tilt, "vertex_px": vpx.tolist()}
    return Scenario("tilt-sweep", camera, sheet, backdrop, frames, seed, opts)


# the hand's motion: three sinusoids per channel (slow drift, sway, shake), periods in frames
# at speed 1, each a share of the channel's peak rate
_HAND_PERIODS = (100.0, 45.0, 17.0)
_HAND_SHARES = (0.6, 0.3, 0.1)


def _hand_channel(rng, s, peak_rate, dims=1):
    """A channel (n, dims) of the hand's motion at times s (n,) [frames at speed 1], zero
    mean, its largest change from one frame to the next at speed 1 (the norm over dims)
    equal to `peak_rate`; (n,) for dims 1."""
    ph = rng.uniform(0.0, 2 * math.pi, (dims, len(_HAND_PERIODS)))

    def at(x):
        return np.stack([sum(sh * T / (2 * math.pi) * np.sin(2 * math.pi * x / T + p)
                             for T, sh, p in zip(_HAND_PERIODS, _HAND_SHARES, phd)) for phd in ph], -1)

    grid = np.arange(0.0, max(float(s[-1]), 1.0) + 1.0)
    out = at(s) * (peak_rate / np.max(np.linalg.norm(np.diff(at(grid), axis=0), axis=-1)))
    return out[:, 0] if dims == 1 else out


def _handheld(camera, sheet, backdrop, n, seed, options):
    """The handheld scenario of `n` frames (make_scenario's options for "handheld")."""
    rng = np.random.default_rng([seed, 4])
    scale = _distance_scale(camera)
    D = float(_option(options, "distance", 400.0 * scale))
    tilt0 = float(_option(options, "tilt_deg", 35.0))
    speed = float(_option(options, "speed", 1.0))
    v_px = float(_option(options, "speed_px", 8.0 * camera.width / 1920.0))
    roll_rate = float(_option(options, "roll_deg", 3.0))
    tilt_rate = float(_option(options, "tilt_rate_deg", 1.0))
    if not (D > 0 and speed > 0 and 0 <= tilt0 < 80 and min(v_px, roll_rate, tilt_rate) >= 0):
        raise InputError("handheld: needs distance > 0, speed > 0, 0 <= tilt_deg < 80 and rates >= 0")
    s = np.arange(n) * speed
    # the vertex's image: two channels whose joint speed peaks at speed_px
    xy = _hand_channel(rng, s, v_px, dims=2)
    roll = np.radians(_hand_channel(rng, s, roll_rate))
    tilt = np.clip(tilt0 + _hand_channel(rng, s, tilt_rate), 0.0, 85.0)
    axis = np.radians(_hand_channel(rng, s, tilt_rate))
    dist = D * (1.0 + 0.05 * np.sin(2 * math.pi * s / _HAND_PERIODS[0] + rng.uniform(0, 2 * math.pi)))
    v = sheet.pencil.vertex
    vt = np.array([v[0], v[1], 0.0])
    names = _names(n)
    frames = []
    for k in range(n):
        ray = camera.rays_from_pixels(camera.K[:2, 2] + xy[k])
        if not np.all(np.isfinite(ray)):
            raise InputError("handheld: the vertex's path leaves the lens model's field of view")
        ray = ray / np.linalg.norm(ray)
        axis_t = np.array([math.cos(axis[k]), math.sin(axis[k]), 0.0])
        R = rotation_about_axis(ray, roll[k]) @ rotation_to_z(ray).T @ rotation_about_axis(axis_t, math.radians(tilt[k]))
        t = ray * dist[k] - R @ vt
        fr = _frame_truth(camera, sheet, R, t, names[k])
        fr["roll_deg"] = float(np.degrees(roll[k]))
        frames.append(fr)
    opts = {"distance": D, "tilt_deg": tilt0, "speed": speed, "speed_px": v_px, "roll_deg": roll_rate,
            "tilt_rate_deg": tilt_rate}
    return Scenario("handheld", camera, sheet, backdrop, frames, seed, opts)
