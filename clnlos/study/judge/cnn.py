"""The seed's CNN recipe (torch, CPU, seeded): the clarity classifier of ``--labels fft`` /
``nr`` (the study's legibility judge is :mod:`clnlos.study.judge.model`).

The seed's recipe (seed Eq. 18-19, ``--labels fft`` / ``nr``): MIP -> label 1/2/3; two conv
blocks (8 and 16 channels, 3x3, ReLU, 2x2 max-pool), a hidden layer of 32, three outputs with a
softmax; cross-entropy, Adam, 10 epochs, an 80/20 split. Training images are augmented by the
eight symmetries of the square (flips and quarter turns): the labels' metrics do not depend on
orientation. Reported: validation accuracy, the majority-class baseline of the validation
split, the confusion matrix, per-epoch loss and accuracy.
"""

from __future__ import annotations

import numpy as np

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
