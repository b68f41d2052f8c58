"""Neural BRDF (torch MLP) fitted to measured samples: the seed recipe and an improved one.

Seed recipe (seed Eq. 16-17): inputs (theta_i, phi_i, theta_s, phi_s), five hidden layers of
20, 30, 20, 10, 10 ReLU units with dropout, linear output, loss
mean(|y - f|^2 / |f|^2) + lambda sum |w| (L1 on the weights), Adam, fixed epochs.

Improved recipe (``recipe="improved"``), each part switchable:
* positive output: the network predicts log f, the output is exp(.) (never negative);
* reciprocity: inputs are the Rusinkiewicz half/difference angles encoded as
  (theta_h, theta_d, cos 2 phi_d, cos theta_i cos theta_s), unchanged when source and detector
  swap (and by the bilateral symmetry of isotropic BRDFs);
* a log-space loss mean((log fhat - log f)^2), which weighs specular peaks and dark tails alike;
* early stopping on a held-out part of the training samples.

Deterministic for a seed (torch.manual_seed, a numpy Generator for the splits).
"""

from __future__ import annotations

from dataclasses import asdict, dataclass

import numpy as np

from .data import BRDFSamples, half_diff

HIDDEN = (20, 30, 20, 10, 10)


@dataclass
class MLPConfig:
    recipe: str = "improved"  # "seed" or "improved"
    epochs: int = 3000
    lr: float = 3e-3
    dropout: float = 0.05
    l1: float = 1e-6
    val_fraction: float = 0.15  # early stopping (improved recipe)
    patience: int = 300
    seed: int = 0

    @property
    def improved(self) -> bool:
        return self.recipe == "improved"


def encode(ti, pi_, ts, ps, improved: bool) -> np.ndarray:
    ti, pi_, ts, ps = (np.asarray(a, float) for a in (ti, pi_, ts, ps))
    if not improved:
        return np.column_stack([ti, np.mod(pi_, 2 * np.pi), ts, np.mod(ps, 2 * np.pi)])
    th, td, pd = half_diff(ti, pi_, ts, ps)
    return np.column_stack([th / (np.pi / 2), td / (np.pi / 2), np.cos(2 * pd),
                            np.cos(ti) * np.cos(ts)])


class NeuralBRDF:
    """A trained network with its input encoding; ``model(ti, pi, ts, ps) -> f`` (1/sr)."""

    def __init__(self, net, config: MLPConfig, log_offset: float):
        self.net, self.config, self.log_offset = net, config, log_offset

    def __call__(self, ti, pi_, ts, ps) -> np.ndarray:
        import torch

        x = encode(ti, pi_, ts, ps, self.config.improved)
        shape = np.broadcast(np.asarray(ti), np.asarray(ts)).shape
        self.net.eval()
        with torch.no_grad():
            y = self.net(torch.from_numpy(x.astype(np.float32))).numpy()[:, 0].astype(float)
        f = np.exp(y) - self.log_offset if self.config.improved else y
        return np.maximum(f, 0).reshape(shape) if self.config.improved else f.reshape(shape)

    def state(self) -> dict:
        return {k: v.detach().numpy() for k, v in self.net.state_dict().items()}

    def meta(self) -> dict:
        return {"config": asdict(self.config), "log_offset": self.log_offset,
                "hidden": list(HIDDEN)}

    @classmethod
    def from_state(cls, state: dict, meta: dict) -> NeuralBRDF:
        import torch

        cfg = MLPConfig(**meta["config"])
        net = build_net(cfg)
        net.load_state_dict({k: torch.from_numpy(np.asarray(v)) for k, v in state.items()})
        return cls(net, cfg, float(meta["log_offset"]))


def build_net(cfg: MLPConfig):
    import torch.nn as nn

    layers, n_in = [], 4
    for h in HIDDEN:
        layers += [nn.Linear(n_in, h), nn.ReLU(), nn.Dropout(cfg.dropout)]
        n_in = h
    layers.append(nn.Linear(n_in, 1))
    return nn.Sequential(*layers)


def train_mlp(train: BRDFSamples, cfg: MLPConfig | None = None) -> tuple[NeuralBRDF, dict]:
    """Train on ``train`` (full batch, Adam); returns the model and a training log."""
    import torch

    cfg = cfg or MLPConfig()
    # a network this small is dominated by per-op threading overhead: one thread is fastest
    threads = torch.get_num_threads()
    torch.set_num_threads(1)
    try:
        return _train(train, cfg)
    finally:
        torch.set_num_threads(threads)


def _train(train: BRDFSamples, cfg: MLPConfig):
    import torch

    torch.manual_seed(cfg.seed)
    rng = np.random.default_rng(cfg.seed)
    x = encode(train.theta_i, train.phi_i, train.theta_s, train.phi_s, cfg.improved)
    f = train.brdf.astype(float)
    pos = f[f > 0]
    offset = 1e-3 * float(np.median(pos)) if pos.size else 1e-6
    idx = rng.permutation(len(f))
    n_val = int(round(cfg.val_fraction * len(f))) if cfg.improved else 0
    val, tr = idx[:n_val], idx[n_val:]
    X = torch.from_numpy(x.astype(np.float32))
    F = torch.from_numpy(f.astype(np.float32))
    net = build_net(cfg)
    opt = torch.optim.Adam(net.parameters(), lr=cfg.lr)
    weights = [p for n, p in net.named_parameters() if n.endswith("weight")]

    def loss_on(ii):
        y = net(X[ii])[:, 0]
        if cfg.improved:
            return torch.mean((y - torch.log(F[ii] + offset)) ** 2)
        fi = F[ii]
        den = torch.clamp(fi, min=offset) ** 2
        return torch.mean((y - fi) ** 2 / den)

    best, best_state, since, log = np.inf, None, 0, []
    tr_t = torch.from_numpy(tr)
    val_t = torch.from_numpy(val)
    for epoch in range(cfg.epochs):
        net.train()
        opt.zero_grad()
        loss = loss_on(tr_t) + cfg.l1 * sum(w.abs().sum() for w in weights)
        loss.backward()
        opt.step()
        if cfg.improved and n_val:
            net.eval()
            with torch.no_grad():
                v = float(loss_on(val_t))
            if v < best - 1e-6:
                best, since = v, 0
                best_state = {k: t.clone() for k, t in net.state_dict().items()}
            else:
                since += 1
                if since > cfg.patience:
                    break
        if epoch % 200 == 0:
            log.append((epoch, float(loss.detach())))
    if best_state is not None:
        net.load_state_dict(best_state)
    net.eval()
    return NeuralBRDF(net, cfg, offset), {"epochs_run": epoch + 1, "loss_log": log}
