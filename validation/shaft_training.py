"""Training the shaft detector's pixel model (`toolkit.detect.shaft.pixels`) on masked frames.

Each frame gives samples of its work frame's pixel features, labelled by its instrument mask
(reduced to the work frame: a pixel is instrument when more than half of its area is),
`samples_per_frame` of them, half instrument and half not where the frame has both. A pixel
within one work pixel of the mask's outline is left out (its label is the annotator's, its
colour a mix). Sources weigh equally whatever their frame counts, and within a source the two
classes do: the model learns what tells instruments from tissue everywhere, not what is
common in the largest source.

The fit is the maximum of the weighted log-likelihood with a small L2 penalty on the weights
(L-BFGS, seeded, repeatable), `hidden` tanh units.

`fold_models` trains the models a leave-one-source-out table needs (`validation.
shaft_protocol`): one without each source, and one without each pair (the others' evidence
when a threshold is chosen for a source must come from a model that saw neither).

The model the package ships (`toolkit/detect/shaft/instrument_pixels.json`) is trained on
every masked real source the project has, by

    python -m pencilcal.validation.shaft_training tests/data/masked_sources.json \
        toolkit/detect/shaft/instrument_pixels.json --data ../shared/data/real-instruments

(`main`: the sources' folders, image and mask globs, labels; each source's valid region
detected from its frames; seed 0).

Example
-------
>>> import numpy as np
>>> rng = np.random.default_rng(0)
>>> img = np.zeros((120, 200, 3), np.uint8); img[:] = (60, 80, 170); img[50:70] = 90
>>> img = np.clip(img + rng.normal(0, 4, img.shape), 0, 255).astype(np.uint8)
>>> mask = np.zeros((120, 200), bool); mask[50:70] = True
>>> X, y = pixel_samples(img, mask, samples_per_frame=400)
>>> m = train_pixel_model({"toy": [(X, y)]}, hidden=4, maxiter=100)
>>> from pencilcal.toolkit.detect.shaft.pixels import pixel_features
>>> p = m.probability(pixel_features(img, np.ones((120, 200), bool)))
>>> bool(p[60, 100] > 0.9), bool(p[20, 100] < 0.1)
(True, True)
"""
from __future__ import annotations

import numpy as np

from pencilcal.toolkit.detect.shaft.pixels import FEATURES, WORK_PX, PixelModel, expanded_inputs, pixel_features
from pencilcal.toolkit.detect.shaft.work import Validity, WorkFrame

__all__ = ["pixel_samples", "train_pixel_model", "fold_models", "read_sources", "main", "SAMPLES_PER_FRAME", "HIDDEN"]

#: Samples drawn from each frame (half instrument, half not).
SAMPLES_PER_FRAME = 4000
#: Hidden units of the model.
HIDDEN = 12
_L2 = 1e-3


def pixel_samples(image, instrument_mask, valid_region=None, camera=None, samples_per_frame=SAMPLES_PER_FRAME,
                  seed=0):
    """(X (N, len(FEATURES)) float32, y (N,) bool) of one frame (module docstring).

    image: (H, W, 3) BGR; instrument_mask: (H, W) bool, every instrument of the frame;
    valid_region: the frame's valid region (`region.ValidRegion` or None)."""
    import cv2

    img = np.asarray(image)
    wf = WorkFrame(img, camera, Validity(valid_region, img.shape[:2]), WORK_PX)
    valid = wf.valid & (wf.dist > 2.0)
    F = pixel_features(wf.bgr, valid)
    m = cv2.resize(np.asarray(instrument_mask, np.float32), (wf.shape[1], wf.shape[0]), interpolation=cv2.INTER_AREA)
    y = m > 0.5
    k3 = np.ones((3, 3), np.uint8)
    edge = cv2.dilate(y.astype(np.uint8), k3) != cv2.erode(y.astype(np.uint8), k3)
    use = valid & ~edge
    rng = np.random.default_rng(seed)
    pos, neg = np.flatnonzero((use & y).ravel()), np.flatnonzero((use & ~y).ravel())
    half = samples_per_frame // 2
    take = [rng.choice(a, min(a.size, half if pos.size and neg.size else samples_per_frame), replace=False)
            for a in (pos, neg) if a.size]
    idx = np.concatenate(take) if take else np.zeros(0, int)
    return F.reshape(-1, len(FEATURES))[idx], y.ravel()[idx]


def train_pixel_model(samples, hidden=HIDDEN, l2=_L2, seed=0, maxiter=300):
    """A `PixelModel` fitted to samples: {source name: [(X, y), ...] per frame} (module
    docstring)."""
    from scipy.optimize import minimize

    Xs, ys, ws = [], [], []
    for frames in samples.values():
        X = np.concatenate([f[0] for f in frames])
        y = np.concatenate([f[1] for f in frames]).astype(float)
        npos, nneg = y.sum(), (1 - y).sum()
        w = np.where(y > 0, 0.5 / max(npos, 1), 0.5 / max(nneg, 1)) / len(samples)
        Xs.append(X)
        ys.append(y)
        ws.append(w)
    X = expanded_inputs(np.concatenate(Xs).astype(np.float64))
    y, w = np.concatenate(ys), np.concatenate(ws)
    w = w / w.sum()
    mu, sd = X.mean(0), X.std(0) + 1e-6
    Z = (X - mu) / sd
    D, H = Z.shape[1], int(hidden)
    rng = np.random.default_rng(seed)
    th0 = np.r_[rng.normal(0, 0.3, D * H), np.zeros(H), rng.normal(0, 0.3, H), 0.0]

    def unpack(th):
        return th[:D * H].reshape(D, H), th[D * H:D * H + H], th[D * H + H:D * H + 2 * H], th[-1]

    def loss(th):
        W1, b1, w2, b2 = unpack(th)
        A = np.tanh(Z @ W1 + b1)
        p = 1.0 / (1.0 + np.exp(-np.clip(A @ w2 + b2, -40, 40)))
        val = -np.sum(w * (y * np.log(p + 1e-12) + (1 - y) * np.log(1 - p + 1e-12))) \
            + l2 * (np.sum(W1 ** 2) + np.sum(w2 ** 2))
        dz = w * (p - y)
        dA = np.outer(dz, w2) * (1 - A * A)
        grad = np.r_[(Z.T @ dA + 2 * l2 * W1).ravel(), dA.sum(0), A.T @ dz + 2 * l2 * w2, dz.sum()]
        return val, grad

    th = minimize(loss, th0, jac=True, method="L-BFGS-B", options={"maxiter": int(maxiter)}).x
    W1, b1, w2, b2 = unpack(th)
    return PixelModel(mu=mu, sd=sd, W1=W1, b1=b1, w2=w2, b2=float(b2), trained_on=tuple(samples))


def fold_models(samples, pairs=True, **options):
    """{frozenset of the sources left out: `PixelModel`} trained on samples ({source: [(X, y)
    per frame]}, `pixel_samples`): without each source and, with pairs, without each pair.
    options: `train_pixel_model`'s."""
    from itertools import combinations

    names = list(samples)
    out = {}
    for k in (1, 2) if pairs else (1,):
        for left in combinations(names, k):
            if len(left) < len(names):
                out[frozenset(left)] = train_pixel_model({n: v for n, v in samples.items() if n not in left}, **options)
    return out


def read_sources(spec, root):
    """{name: [(image (H, W, 3) uint8, instrument mask (H, W) bool, valid region)]} of a
    sources file (JSON: {name: {"folder", "images", "masks", "labels" (values, or B, G, R
    colours; null: every non-zero), "instances"}}) under root; images and masks paired in
    sorted order, each source's valid region detected from its frames."""
    import json
    from pathlib import Path

    import cv2

    from pencilcal.toolkit.detect.region.detect import detect_valid_region
    from pencilcal.toolkit.detect.shaft.mask import instruments_in_mask
    from pencilcal.toolkit.errors import InputError

    out = {}
    for name, s in json.loads(Path(spec).read_text()).items():
        folder = Path(root) / s["folder"]
        paths, masks = sorted(folder.glob(s["images"])), sorted(folder.glob(s["masks"]))
        if not paths or len(paths) != len(masks):
            raise InputError(f"{spec}: source {name}: {len(paths)} images and {len(masks)} masks under {folder}")
        images = [cv2.imread(str(q)) for q in paths]
        region = detect_valid_region(images)
        labels = None if s.get("labels") is None else [tuple(v) if isinstance(v, list) else v for v in s["labels"]]
        frames = []
        for img, mp in zip(images, masks):
            inst = instruments_in_mask(cv2.imread(str(mp), cv2.IMREAD_UNCHANGED), labels, bool(s.get("instances")))
            frames.append((img, np.any(inst, 0) if inst else np.zeros(img.shape[:2], bool), region))
        out[name] = frames
    return out


def main(argv=None):
    """Train the pixel model on a sources file and write it (module docstring)."""
    import argparse

    from pencilcal.toolkit.io.files import write_json

    ap = argparse.ArgumentParser(prog="python -m pencilcal.validation.shaft_training", description=__doc__.split("\n")[0])
    ap.add_argument("sources", help="JSON sources file (read_sources)")
    ap.add_argument("out", help="the model's JSON file")
    ap.add_argument("--data", required=True, help="the folder the sources' folders are in")
    a = ap.parse_args(argv)
    samples = {n: [pixel_samples(img, m, reg) for img, m, reg in frames]
               for n, frames in read_sources(a.sources, a.data).items()}
    write_json(a.out, train_pixel_model(samples).to_dict(), force=True, indent=None)


if __name__ == "__main__":
    main()
