"""CNN clarity classifier (seed Eq. 18-19): reconstructed MIP -> label 1/2/3.

Two conv blocks (8 and 16 channels, 3x3, ReLU, 2x2 max-pool), a hidden layer of 32, three
outputs with a softmax; cross-entropy, Adam, 10 epochs, an 80/20 split (800/200 of 1000),
all seeded.
"""

from __future__ import annotations

import numpy as np


def _net(n: int):
    import torch.nn as nn

    side = n // 4
    return nn.Sequential(
        nn.Conv2d(1, 8, 3, padding=1), nn.ReLU(), nn.MaxPool2d(2),
        nn.Conv2d(8, 16, 3, padding=1), nn.ReLU(), nn.MaxPool2d(2),
        nn.Flatten(), nn.Linear(16 * side * side, 32), nn.ReLU(), nn.Linear(32, 3))


def train_classifier(images: np.ndarray, labels: np.ndarray, *, epochs: int = 10,
                     val_fraction: float = 0.2, seed: int = 0, batch: int = 32):
    """Returns (predict function: images -> (labels 1..3, softmax probs), report dict)."""
    import torch

    torch.manual_seed(seed)
    rng = np.random.default_rng(seed)
    X = torch.from_numpy(np.asarray(images, np.float32)[:, None])
    y = torch.from_numpy(np.asarray(labels, np.int64) - 1)
    idx = rng.permutation(len(y))
    n_val = int(round(val_fraction * len(y)))
    val, tr = idx[:n_val], idx[n_val:]
    net = _net(images.shape[-1])
    opt = torch.optim.Adam(net.parameters(), lr=2e-3)
    lossf = torch.nn.CrossEntropyLoss()
    history = []
    for _ in range(epochs):
        net.train()
        perm = tr[rng.permutation(len(tr))]
        tot = 0.0
        for b in range(0, len(perm), batch):
            ii = torch.from_numpy(perm[b:b + batch])
            opt.zero_grad()
            loss = lossf(net(X[ii]), y[ii])
            loss.backward()
            opt.step()
            tot += float(loss.detach()) * len(ii)
        history.append(tot / max(len(tr), 1))
    net.eval()

    def predict(imgs):
        with torch.no_grad():
            p = torch.softmax(net(torch.from_numpy(np.asarray(imgs, np.float32)[:, None])), 1)
        return p.argmax(1).numpy() + 1, p.numpy()

    pv, _ = predict(images[val]) if n_val else (np.zeros(0, int), None)
    yv = labels[val]
    conf = np.zeros((3, 3), int)
    for t, p in zip(yv, pv, strict=True):
        conf[t - 1, p - 1] += 1
    acc = float((pv == yv).mean()) if n_val else float("nan")
    return predict, {"val_accuracy": acc, "confusion": conf.tolist(), "train_loss": history,
                     "n_train": int(len(tr)), "n_val": int(n_val), "epochs": epochs}
