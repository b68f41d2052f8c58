"""The study's CNNs (torch, CPU, seeded): the seed's clarity classifier and the legibility
classifier.

The seed's recipe (seed Eq. 18-19, ``--labels fft`` / ``nr``): MIP -> label 1/2/3; two conv
blocks (8 and 16 channels, 3x3, ReLU, 2x2 max-pool), a hidden layer of 32, three outputs with a
softmax; cross-entropy, Adam, 10 epochs, an 80/20 split. Training images are augmented by the
eight symmetries of the square (flips and quarter turns): the labels' metrics do not depend on
orientation. Reported: validation accuracy, the majority-class baseline of the validation
split, the confusion matrix, per-epoch loss and accuracy.

The legibility classifier (:func:`fit_legibility`): MIP -> P(legible), legible meaning the
template rule identified the glyph *and* its IoU beats the box baseline
(:func:`clnlos.study.samples.legibility_label` class 1: read, and more shape than a blob). Four
conv blocks (3x3, stride 2, batch norm, ReLU; 8-16-32-64 channels), a 2 x 2 average pool, a
hidden layer of 32 and two heads: the logit z of "legible" and the IoU over the box baseline
(a regression that shares the features). Loss: class-balanced binary cross-entropy (each
class weighs half) + AUX_WEIGHT x the second head's squared error; Adam with a cosine
schedule over LEGIBILITY_EPOCHS, one random view of every image per epoch (:func:`augmented`:
symmetry of the square, zoom, shift, blur, noise); batch-norm statistics then recomputed on
the clean images. One thread, seeded: the same inputs give the same network.

Its probability. Trained class-balanced, z estimates the log likelihood ratio of legible to
not; the posterior is

    P(legible) = sigmoid(z + log(pi / (1 - pi))),

pi the training split's share of legible reconstructions (logit adjustment: what undoes the
balancing, no parameter fitted), z averaged over the eight symmetries of the image.
"""

from __future__ import annotations

import numpy as np
from scipy import ndimage

SEED_EPOCHS = 10


def _net(n: int, n_classes: int = 3):
    import torch.nn as nn

    side = n // 4
    return nn.Sequential(
        nn.Conv2d(1, 8, 3, padding=1), nn.ReLU(), nn.MaxPool2d(2),
        nn.Conv2d(8, 16, 3, padding=1), nn.ReLU(), nn.MaxPool2d(2),
        nn.Flatten(), nn.Linear(16 * side * side, 32), nn.ReLU(), nn.Linear(32, n_classes))


def dihedral(images: np.ndarray) -> np.ndarray:
    """The eight flips/quarter turns of each image [n, y, x] -> [8 n, y, x]."""
    views = []
    for k in range(4):
        r = np.rot90(images, k, axes=(1, 2))
        views += [r, r[:, :, ::-1]]
    return np.ascontiguousarray(np.concatenate(views))


def train_classifier(images: np.ndarray, labels: np.ndarray, *, epochs: int = SEED_EPOCHS,
                     val_fraction: float = 0.2, seed: int = 0, batch: int = 32,
                     augment: bool = True, progress=None, n_classes: int = 3,
                     val_mask: np.ndarray | None = None):
    """Returns (predict function: images -> (labels 1..n_classes, softmax probs), report).

    The validation split is a random ``val_fraction``, or the samples where ``val_mask`` is
    true (held-out glyphs and geometries). ``progress(done, total)`` is called after every
    training batch: ``done`` batches of ``total`` = epochs x batches per epoch."""
    import torch

    torch.manual_seed(seed)
    rng = np.random.default_rng(seed)
    images = np.asarray(images, np.float32)
    labels = np.asarray(labels, np.int64)
    idx = rng.permutation(len(labels))
    if val_mask is None:
        n_val = int(round(val_fraction * len(labels)))
        val, tr = idx[:n_val], idx[n_val:]
    else:
        held = np.asarray(val_mask, bool)
        val, tr = idx[held[idx]], idx[~held[idx]]
        n_val = len(val)
    x_tr, y_tr = images[tr], labels[tr]
    if augment:
        x_tr, y_tr = dihedral(x_tr), np.tile(y_tr, 8)
    X = torch.from_numpy(x_tr[:, None])
    Y = torch.from_numpy(y_tr - 1)
    Xv = torch.from_numpy(images[val][:, None])
    Yv = torch.from_numpy(labels[val] - 1)
    net = _net(images.shape[-1], n_classes)
    opt = torch.optim.Adam(net.parameters(), lr=2e-3)
    lossf = torch.nn.CrossEntropyLoss()
    history = {"train_loss": [], "val_loss": [], "train_accuracy": [], "val_accuracy": []}
    per_epoch = -(-len(Y) // batch)  # batches per epoch
    for epoch in range(epochs):
        net.train()
        perm = rng.permutation(len(Y))
        tot, hit = 0.0, 0
        for b in range(0, len(perm), batch):
            ii = torch.from_numpy(perm[b:b + batch])
            opt.zero_grad()
            out = net(X[ii])
            loss = lossf(out, Y[ii])
            loss.backward()
            opt.step()
            tot += float(loss.detach()) * len(ii)
            hit += int((out.argmax(1) == Y[ii]).sum())
            if progress is not None:
                progress(epoch * per_epoch + b // batch + 1, epochs * per_epoch)
        history["train_loss"].append(tot / max(len(Y), 1))
        history["train_accuracy"].append(hit / max(len(Y), 1))
        net.eval()
        with torch.no_grad():
            out = net(Xv) if n_val else None
        history["val_loss"].append(float(lossf(out, Yv)) if n_val else float("nan"))
        history["val_accuracy"].append(float((out.argmax(1) == Yv).float().mean())
                                        if n_val else float("nan"))

    def predict(imgs):
        with torch.no_grad():
            p = torch.softmax(net(torch.from_numpy(np.asarray(imgs, np.float32)[:, None])), 1)
        return p.argmax(1).numpy() + 1, p.numpy()

    pv, _ = predict(images[val]) if n_val else (np.zeros(0, int), None)
    yv = labels[val]
    conf = np.zeros((n_classes, n_classes), int)
    for t, p in zip(yv, pv, strict=True):
        conf[t - 1, p - 1] += 1
    acc = float((pv == yv).mean()) if n_val else float("nan")
    majority = (float(np.bincount(yv, minlength=n_classes + 1)[1:].max() / len(yv)) if n_val
                else float("nan"))
    return predict, {"val_accuracy": acc, "majority_baseline": majority,
                     "confusion": conf.tolist(), "train_loss": history["train_loss"],
                     "val_loss": history["val_loss"],
                     "train_accuracy": history["train_accuracy"],
                     "val_accuracy_per_epoch": history["val_accuracy"],
                     "n_train": int(len(tr)), "n_val": int(n_val), "epochs": epochs,
                     "augmented": bool(augment)}




# ------------------------------------------------------------------ the legibility classifier
LEGIBILITY_EPOCHS = 40
LEGIBILITY_BATCH = 64
LEGIBILITY_LR = 3e-3
LEGIBILITY_WEIGHT_DECAY = 1e-4
LEGIBILITY_CHANNELS = (8, 16, 32, 64)
LEGIBILITY_HIDDEN = 32
LEGIBILITY_DROPOUT = 0.2
AUX_WEIGHT = 0.5          # the IoU-over-baseline head's share of the loss
AUG_ZOOM = 1.4            # zoom by up to this factor either way (letter size / scan width)
AUG_SHIFT_CELLS = 1.0     # shift by up to this many cells (the template rule's tolerance)
AUG_BLUR_MAX_CELLS = 0.5  # Gaussian blur: sigma up to this many cells ...
AUG_BLUR_PROB = 0.5       # ... on this share of the views
AUG_NOISE_MAX = 0.03      # additive Gaussian noise: std up to this fraction of the maximum


def legibility_net():
    """The legibility network (module docstring): [n, 1, y, x] -> [n, 2] (logit, IoU over
    the box baseline), any image size."""
    import torch.nn as nn

    layers, c_in = [], 1
    for c in LEGIBILITY_CHANNELS:
        layers += [nn.Conv2d(c_in, c, 3, stride=2, padding=1), nn.BatchNorm2d(c), nn.ReLU()]
        c_in = c
    return nn.Sequential(*layers, nn.AdaptiveAvgPool2d(2), nn.Flatten(),
                         nn.Linear(4 * c_in, LEGIBILITY_HIDDEN), nn.ReLU(),
                         nn.Dropout(LEGIBILITY_DROPOUT), nn.Linear(LEGIBILITY_HIDDEN, 2))


def normalised(images) -> np.ndarray:
    """Each image [n, y, x] over its maximum (float32; an all-zero image stays zero)."""
    a = np.asarray(images, np.float32)
    m = a.reshape(len(a), -1).max(axis=1) if len(a) else np.zeros(0, np.float32)
    return a / np.where(m > 0, m, 1.0)[:, None, None]


def dihedral_view(image: np.ndarray, k: int) -> np.ndarray:
    """The k-th (0..7) of the eight flips / quarter turns of one image [y, x]."""
    r = np.rot90(image, k // 2)
    return r[:, ::-1] if k % 2 else r


def all_views(images: np.ndarray) -> np.ndarray:
    """The eight views of every image [n, y, x] -> [8 n, y, x], view-major."""
    return np.ascontiguousarray(np.concatenate(
        [np.stack([dihedral_view(v, k) for v in images]) for k in range(8)]))


def augmented(images: np.ndarray, rng: np.random.Generator) -> np.ndarray:
    """One random view of each image [n, y, x]: a symmetry of the square, a zoom by up to
    AUG_ZOOM either way and a shift of up to AUG_SHIFT_CELLS (one linear resampling), a
    Gaussian blur of up to AUG_BLUR_MAX_CELLS (on AUG_BLUR_PROB of them) and Gaussian noise
    of up to AUG_NOISE_MAX; clipped at 0 and renormalised to a maximum of 1."""
    out = np.empty_like(images)
    centre = (np.array(images.shape[1:], float) - 1) / 2
    for i, img in enumerate(images):
        v = dihedral_view(img, int(rng.integers(8)))
        zoom = float(np.exp(rng.uniform(-1, 1) * np.log(AUG_ZOOM)))
        shift = rng.uniform(-AUG_SHIFT_CELLS, AUG_SHIFT_CELLS, 2)
        # output cell o samples the input at centre + (o - centre - shift) / zoom
        v = ndimage.affine_transform(v, np.full(2, 1 / zoom),
                                     offset=centre - (centre + shift) / zoom, order=1,
                                     mode="constant")
        if rng.random() < AUG_BLUR_PROB:
            v = ndimage.gaussian_filter(v, rng.uniform(0, AUG_BLUR_MAX_CELLS), mode="constant")
        out[i] = v + rng.normal(0.0, rng.uniform(0, AUG_NOISE_MAX), v.shape)
    return normalised(np.clip(out, 0.0, None))


def class_weights(y) -> np.ndarray:
    """Per-sample weights n / (2 n_class): both classes weigh half of the loss."""
    y = np.asarray(y, bool)
    n, pos = len(y), int(y.sum())
    w_pos = n / (2 * pos) if pos else 0.0
    w_neg = n / (2 * (n - pos)) if n > pos else 0.0
    return np.where(y, w_pos, w_neg).astype(np.float32)


def prior_log_odds(y) -> float:
    """log(pi / (1 - pi)) of the share pi of positives in ``y``, pi kept within
    [1/(n+2), (n+1)/(n+2)] (Laplace's rule: finite for a split of one class)."""
    y = np.asarray(y, bool)
    pi = (y.sum() + 1) / (len(y) + 2)
    return float(np.log(pi / (1 - pi)))


class LegibilityClassifier:
    """A trained :func:`legibility_net` with its prior log-odds (module docstring)."""

    def __init__(self, net, log_odds: float):
        self.net, self.log_odds = net, float(log_odds)

    def logits(self, images) -> np.ndarray:
        """The class-balanced logit z of each image [n, y, x], the mean over its 8 views."""
        import torch

        x = normalised(images)
        if not len(x):
            return np.zeros(0)
        self.net.eval()
        with torch.no_grad():
            z = self.net(torch.from_numpy(all_views(x)[:, None]))[:, 0]
        return z.numpy().astype(np.float64).reshape(8, len(x)).mean(axis=0)

    def predict_proba(self, images) -> np.ndarray:
        """P(legible) of each image [n, y, x]: sigmoid(z + log-odds of the training prior)."""
        return 1.0 / (1.0 + np.exp(-(self.logits(images) + self.log_odds)))

    def state(self) -> dict:
        """Picklable state (numpy arrays): what :meth:`from_state` rebuilds it from."""
        return {"log_odds": self.log_odds,
                "net": {k: v.numpy().copy() for k, v in self.net.state_dict().items()}}

    @classmethod
    def from_state(cls, state: dict) -> LegibilityClassifier:
        import torch

        net = legibility_net()
        net.load_state_dict({k: torch.from_numpy(np.asarray(v))
                             for k, v in state["net"].items()})
        net.eval()
        return cls(net, state["log_odds"])


class LegibilityEnsemble:
    """The mean P(legible) of several classifiers (the held-out folds' networks)."""

    def __init__(self, members):
        self.members = list(members)

    def predict_proba(self, images) -> np.ndarray:
        return np.mean([m.predict_proba(images) for m in self.members], axis=0)


def refresh_batch_norm(net, images: np.ndarray) -> None:
    """Batch-norm statistics of the clean ``images`` [n, y, x] in all eight views (what the
    network sees when it predicts), in place of the running averages over augmented
    batches."""
    import torch

    for m in net.modules():
        if isinstance(m, torch.nn.BatchNorm2d):
            m.reset_running_stats()
            m.momentum = None  # a cumulative average over the batches below
    views = all_views(images)
    net.train()
    with torch.no_grad():
        for b in range(0, len(views), 256):
            net(torch.from_numpy(views[b:b + 256][:, None]))
    net.eval()


def fit_legibility(images, legible, iou_excess=None, *, epochs: int = LEGIBILITY_EPOCHS,
                   seed: int = 0, progress=None) -> tuple[LegibilityClassifier, dict]:
    """Train the legibility classifier (module docstring) on MIPs [n, y, x] with labels
    ``legible`` (bool) and, when given, the IoU over the box baseline for the second head.
    Returns the classifier and ``{"train_loss": per epoch, "epochs", "n_train"}``.
    ``progress(done, total)`` is called after every batch."""
    import torch

    threads = torch.get_num_threads()
    torch.set_num_threads(1)  # nets this small are dominated by per-op threading overhead
    try:
        torch.manual_seed(seed)
        rng = np.random.default_rng(seed)
        x = normalised(images)
        y = np.asarray(legible, bool)
        aux = np.zeros(len(y), np.float32) if iou_excess is None else np.asarray(
            iou_excess, np.float32)
        aux_weight = 0.0 if iou_excess is None else AUX_WEIGHT
        w = class_weights(y)
        net = legibility_net()
        opt = torch.optim.Adam(net.parameters(), lr=LEGIBILITY_LR,
                               weight_decay=LEGIBILITY_WEIGHT_DECAY)
        per_epoch = -(-len(y) // LEGIBILITY_BATCH)
        sched = torch.optim.lr_scheduler.CosineAnnealingLR(opt, max(1, epochs * per_epoch))
        losses = []
        for epoch in range(epochs):
            net.train()
            perm = rng.permutation(len(y))
            xa = torch.from_numpy(augmented(x[perm], rng)[:, None])
            ya, wa, ea = (torch.from_numpy(a[perm]) for a in (y.astype(np.float32), w, aux))
            total = 0.0
            for k, b in enumerate(range(0, len(y), LEGIBILITY_BATCH)):
                sl = slice(b, b + LEGIBILITY_BATCH)
                opt.zero_grad()
                out = net(xa[sl])
                loss = torch.nn.functional.binary_cross_entropy_with_logits(
                    out[:, 0], ya[sl], weight=wa[sl])
                loss = loss + aux_weight * torch.mean((out[:, 1] - ea[sl]) ** 2)
                loss.backward()
                opt.step()
                sched.step()
                total += float(loss.detach()) * len(ya[sl])
                if progress is not None:
                    progress(epoch * per_epoch + k + 1, epochs * per_epoch)
            losses.append(total / max(len(y), 1))
        refresh_batch_norm(net, x)
        return (LegibilityClassifier(net, prior_log_odds(y)),
                {"train_loss": losses, "epochs": epochs, "n_train": int(len(y))})
    finally:
        torch.set_num_threads(threads)


def fit_legibility_state(images, legible, iou_excess, epochs: int, seed: int) -> dict:
    """:func:`fit_legibility` for a worker process: the classifier's :meth:`state` and the
    training log."""
    clf, log = fit_legibility(images, legible, iou_excess, epochs=epochs, seed=seed)
    return {**clf.state(), "log": log}
