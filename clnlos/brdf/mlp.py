"""Neural BRDF (torch MLP) fitted to measured samples: the seed recipe and one that keeps peaks.

Seed recipe (``recipe="seed"``, CLI ``mlp-seed``; seed Eq. 16-17): inputs
(theta_i, phi_i, theta_s, phi_s), five hidden layers of 20, 30, 20, 10, 10 ReLU units with
dropout, linear output, loss mean(|y - f|^2 / |f|^2) + lambda sum |w|, Adam, fixed epochs.

Improved recipe (``recipe="improved"``, CLI ``mlp``):

* **output** z = log f; f = exp(z) > 0 with no clamp, so a peak of 1e4 1/sr is as reachable
  as a tail of 1e-3;
* **loss** Huber(beta) of log(f_hat + p) - log(f + p), a relative error that weighs the lobe and
  the tails alike; p = ``floor_fraction`` x the data's significance floor (its precision, at
  least 0.01 1/sr), so values below the precision carry no weight (they are quantisation noise);
* **inputs** Rusinkiewicz half/difference angles, chosen so the lobe is easy: sqrt(theta_h)
  (MERL's resolution near the peak), theta_h, log(theta_h), theta_d, and the azimuth only through
  functions of 2 phi_d (cos 2phi_d, sin^2 theta_d cos 2phi_d, sin^2 theta_d sin 2phi_d), plus
  cos theta_i cos theta_s and cos theta_d, and ``fourier`` sine/cosine harmonics of
  log theta_h and theta_d. Swapping source and detector maps phi_d to phi_d + pi and leaves every
  input unchanged, so the model is **reciprocal by construction**. The sin 2phi_d term is kept
  because measured data are not mirror symmetric (MERL-fitted sets are chiral).
* **albedo** the directional albedo a(theta_i) = int f cos theta_s dw_s, by a quadrature that
  resolves a 0.01 degree lobe (log-spaced in theta_h, Jacobian 4 (w_i . h) cos theta_s), is
  penalised above 1 during training and the trained model is scaled so max a <= 1
  (``albedo_cap``);
* SiLU network ``depth`` x ``width``, AdamW with a cosine schedule, full batch, the weights with
  the lowest loss on a held-out ``val_fraction`` kept; ``members`` networks from consecutive
  seeds combined by the median of log f.

Deterministic for a seed (torch.manual_seed, numpy Generators for splits).
"""

from __future__ import annotations

import math
from dataclasses import asdict, dataclass

import numpy as np

from clnlos.brdf.data import BRDFSamples, half_diff, significance_floor
from clnlos.errors import ParameterError

SEED_HIDDEN = (20, 30, 20, 10, 10)
RECIPES = ("improved", "seed")


@dataclass(frozen=True)
class MLPConfig:
    recipe: str = "improved"      # "improved" or "seed"
    epochs: int = 4000
    lr: float = 3e-3
    seed: int = 0
    # seed recipe
    dropout: float = 0.05
    l1: float = 1e-6
    # improved recipe
    width: int = 64
    depth: int = 3
    fourier: int = 3
    huber_beta: float = 0.1       # in log f (0.1 = 10% relative error)
    floor_fraction: float = 0.1   # p = floor_fraction x significance floor (1/sr)
    val_fraction: float = 0.15
    check_every: int = 10         # epochs between validation checks
    weight_decay: float = 0.0     # AdamW decoupled weight decay
    albedo_weight: float = 1.0
    albedo_cap: bool = True
    members: int = 5

    @property
    def improved(self) -> bool:
        return self.recipe == "improved"


# ------------------------------------------------------------------ encodings
def encode_seed(ti, pi_, ts, ps) -> np.ndarray:
    ti, pi_, ts, ps = (np.asarray(a, float).ravel() for a in np.broadcast_arrays(ti, pi_, ts, ps))
    return np.column_stack([ti, np.mod(pi_, 2 * np.pi), ts, np.mod(ps, 2 * np.pi)])


def encode_reciprocal(ti, pi_, ts, ps, fourier: int) -> np.ndarray:
    """Inputs of the improved recipe (see the module docstring); symmetric in (i, s)."""
    ti, pi_, ts, ps = (np.asarray(a, float).ravel() for a in np.broadcast_arrays(ti, pi_, ts, ps))
    th, td, pd = half_diff(ti, pi_, ts, ps)
    u, d = th / (np.pi / 2), td / (np.pi / 2)
    log_h = np.log(np.degrees(th) + 0.1) / np.log(90.0)
    s2 = np.sin(td) ** 2
    cols = [np.sqrt(u), u, d, np.cos(2 * pd), np.cos(ti) * np.cos(ts), s2 * np.cos(2 * pd),
            s2 * np.sin(2 * pd), np.cos(td), log_h]
    for k in range(1, fourier + 1):
        cols += [np.sin(k * np.pi * log_h), np.cos(k * np.pi * log_h),
                 np.sin(k * np.pi * d), np.cos(k * np.pi * d)]
    return np.column_stack(cols)


def n_inputs(cfg: MLPConfig) -> int:
    return 9 + 4 * cfg.fourier if cfg.improved else 4


# ------------------------------------------------------------------ albedo quadrature
def albedo_quadrature(theta_i_deg=(0, 16, 32, 48, 64, 80), n_theta_h: int = 48,
                      n_phi_h: int = 16, theta_h_min: float = 1e-4, shift=(0.5, 0.5)):
    """Nodes and weights for a(theta_i) = int f(w_i, w_o) cos theta_o dw_o (dimensionless).

    Integrates over the half vector h: dw_o = 4 (w_i . h) dw_h, theta_h log-spaced from
    ``theta_h_min`` rad to pi/2 (midpoint rule in log theta_h), phi_h uniform; directions below
    the horizon get no weight. ``shift`` in [0, 1)^2 moves the nodes within their cells
    (0.5 = midpoints); training cycles through shifted rules so the network cannot hide mass
    between fixed nodes. Returns (angles (n, 4) rad, weights (n,), group (n,) index into
    ``theta_i_deg``)."""
    ti = np.radians(np.asarray(theta_i_deg, float))
    span = math.log((np.pi / 2) / theta_h_min)
    v = (np.arange(n_theta_h) + shift[0]) / n_theta_h
    th = theta_h_min * np.exp(v * span)
    dth = th * span / n_theta_h
    ph = (np.arange(n_phi_h) + shift[1]) / n_phi_h * 2 * np.pi
    TI, TH, PH = np.meshgrid(ti, th, ph, indexing="ij")
    G = np.broadcast_to(np.arange(len(ti))[:, None, None], TI.shape)
    DTH = np.broadcast_to(dth[None, :, None], TI.shape)
    wi = np.stack([np.sin(TI), np.zeros_like(TI), np.cos(TI)], -1)
    h = np.stack([np.sin(TH) * np.cos(PH), np.sin(TH) * np.sin(PH), np.cos(TH)], -1)
    ih = (wi * h).sum(-1)
    wo = 2 * ih[..., None] * h - wi
    ok = (ih > 0) & (wo[..., 2] > 1e-6)
    w = 4 * ih * wo[..., 2] * np.sin(TH) * DTH * (2 * np.pi / n_phi_h)
    ts = np.arccos(np.clip(wo[..., 2], -1, 1))
    ps = np.arctan2(wo[..., 1], wo[..., 0])
    ang = np.column_stack([TI[ok], np.zeros(ok.sum()), ts[ok], ps[ok]])
    return ang, w[ok], G[ok]


# training penalises the albedo on coarse rules (cheap per epoch; TRAIN_SHIFTS shifted copies
# used in turn); the final cap and the reported albedo use a fine one (about 0.1% error).
TRAIN_QUADRATURE = {"theta_i_deg": (0, 30, 55, 80), "n_theta_h": 32, "n_phi_h": 8}
TRAIN_SHIFTS = 8
CHECK_QUADRATURE = {"n_theta_h": 160, "n_phi_h": 64}


def directional_albedo(model, **quad) -> np.ndarray:
    """a(theta_i) of any ``model(ti, pi, ts, ps) -> f`` at the quadrature's incidence angles
    (the fine CHECK_QUADRATURE unless told otherwise)."""
    ang, w, g = albedo_quadrature(**{**CHECK_QUADRATURE, **quad})
    f = model(ang[:, 0], ang[:, 1], ang[:, 2], ang[:, 3])
    return np.bincount(g, weights=w * f)


# ------------------------------------------------------------------ model
class NeuralBRDF:
    """Trained network(s) with their encoding; ``model(ti, pi, ts, ps) -> f`` (1/sr)."""

    def __init__(self, nets, config: MLPConfig, log_scale: float = 0.0):
        self.nets = list(nets)
        self.config = config
        self.log_scale = float(log_scale)  # log of the albedo cap factor (<= 0)

    def _encode(self, ti, pi_, ts, ps):
        if self.config.improved:
            return encode_reciprocal(ti, pi_, ts, ps, self.config.fourier)
        return encode_seed(ti, pi_, ts, ps)

    def log_f(self, ti, pi_, ts, ps) -> np.ndarray:
        """Median over the members of the predicted log f (improved recipe)."""
        import torch

        x = torch.from_numpy(self._encode(ti, pi_, ts, ps).astype(np.float32))
        with torch.no_grad():
            z = np.stack([n.eval()(x).numpy()[:, 0].astype(float) for n in self.nets])
        return np.median(z, axis=0) + self.log_scale

    def __call__(self, ti, pi_, ts, ps) -> np.ndarray:
        import torch

        shape = np.broadcast(*(np.asarray(a) for a in (ti, pi_, ts, ps))).shape
        if self.config.improved:
            return np.exp(self.log_f(ti, pi_, ts, ps)).reshape(shape)
        x = torch.from_numpy(encode_seed(ti, pi_, ts, ps).astype(np.float32))
        with torch.no_grad():
            return self.nets[0].eval()(x).numpy()[:, 0].astype(float).reshape(shape)

    def state(self) -> dict:
        return {f"{m}.{k}": v.detach().numpy() for m, n in enumerate(self.nets)
                for k, v in n.state_dict().items()}

    def meta(self) -> dict:
        return {"config": asdict(self.config), "log_scale": self.log_scale,
                "members": len(self.nets)}

    @classmethod
    def from_state(cls, state: dict, meta: dict) -> NeuralBRDF:
        import torch

        cfg = MLPConfig(**meta["config"])
        nets = []
        for m in range(int(meta.get("members", 1))):
            net = build_net(cfg)
            net.load_state_dict({k.split(".", 1)[1]: torch.from_numpy(np.asarray(v))
                                 for k, v in state.items() if k.split(".", 1)[0] == str(m)})
            nets.append(net)
        return cls(nets, cfg, float(meta.get("log_scale", 0.0)))


def build_net(cfg: MLPConfig):
    import torch.nn as nn

    layers, n_in = [], n_inputs(cfg)
    if cfg.improved:
        for _ in range(cfg.depth):
            layers += [nn.Linear(n_in, cfg.width), nn.SiLU()]
            n_in = cfg.width
    else:
        for h in SEED_HIDDEN:
            layers += [nn.Linear(n_in, h), nn.ReLU(), nn.Dropout(cfg.dropout)]
            n_in = h
    layers.append(nn.Linear(n_in, 1))
    return nn.Sequential(*layers)


# ------------------------------------------------------------------ training
def train_mlp(train: BRDFSamples, cfg: MLPConfig | None = None, *,
              progress=None) -> tuple[NeuralBRDF, dict]:
    """Fit ``train`` with ``cfg``'s recipe; returns the model and a training log.

    ``progress(done, total)`` is called after every epoch of every network: ``done`` epochs
    of ``total`` = epochs x networks (``members`` for the improved recipe, 1 for the seed's).
    """
    import torch

    cfg = cfg or MLPConfig()
    if cfg.recipe not in RECIPES:
        raise ParameterError("recipe", cfg.recipe, " or ".join(RECIPES))
    networks = cfg.members if cfg.improved else 1

    def epoch_done(member: int):  # member m's epochs -> the count over all networks
        if progress is None:
            return None
        return lambda e: progress(member * cfg.epochs + e, networks * cfg.epochs)
    # networks this small are dominated by per-op threading overhead: one thread is fastest
    threads = torch.get_num_threads()
    torch.set_num_threads(1)
    try:
        if not cfg.improved:
            net, log = _train_seed(train, cfg, epoch_done(0))
            return NeuralBRDF([net], cfg), log
        nets, logs = [], []
        for m in range(cfg.members):
            net, log = _train_improved(train, cfg, cfg.seed + m, epoch_done(m))
            nets.append(net)
            logs.append(log)
        model = NeuralBRDF(nets, cfg)
        albedo = directional_albedo(model)
        if cfg.albedo_cap and albedo.max() > 1.0:
            model.log_scale = -math.log(float(albedo.max()))
        return model, {"epochs_run": [lg["epochs_run"] for lg in logs],
                       "best_val_loss": [lg["best_val_loss"] for lg in logs],
                       "max_albedo_before_cap": float(albedo.max()),
                       "loss_floor_per_sr": logs[0]["loss_floor_per_sr"]}
    finally:
        torch.set_num_threads(threads)


def _train_seed(train: BRDFSamples, cfg: MLPConfig, epoch_done=None):
    import torch

    torch.manual_seed(cfg.seed)
    X = torch.from_numpy(encode_seed(train.theta_i, train.phi_i, train.theta_s,
                                     train.phi_s).astype(np.float32))
    f = train.brdf.astype(float)
    pos = f[f > 0]
    eps = 1e-3 * float(np.median(pos)) if pos.size else 1e-6
    F = torch.from_numpy(f.astype(np.float32))
    den = torch.clamp(F, min=eps) ** 2
    net = build_net(cfg)
    opt = torch.optim.Adam(net.parameters(), lr=cfg.lr)
    weights = [p for n, p in net.named_parameters() if n.endswith("weight")]
    log = []
    for epoch in range(cfg.epochs):
        net.train()
        opt.zero_grad()
        loss = torch.mean((net(X)[:, 0] - F) ** 2 / den) + cfg.l1 * sum(
            w.abs().sum() for w in weights)
        loss.backward()
        opt.step()
        if epoch % 200 == 0:
            log.append((epoch, float(loss.detach())))
        if epoch_done is not None:
            epoch_done(epoch + 1)
    net.eval()
    return net, {"epochs_run": cfg.epochs, "loss_log": log}


def _train_improved(train: BRDFSamples, cfg: MLPConfig, seed: int, epoch_done=None):
    import torch
    import torch.nn.functional as tf

    torch.manual_seed(seed)
    rng = np.random.default_rng(seed)
    p = cfg.floor_fraction * significance_floor(train)
    X = torch.from_numpy(encode_reciprocal(train.theta_i, train.phi_i, train.theta_s,
                                           train.phi_s, cfg.fourier).astype(np.float32))
    T = torch.from_numpy(np.log(train.brdf.astype(float) + p).astype(np.float32))
    log_p = math.log(p)
    idx = rng.permutation(len(T))
    n_val = int(round(cfg.val_fraction * len(T)))
    val, fit = torch.from_numpy(idx[:n_val]), torch.from_numpy(idx[n_val:])
    net = build_net(cfg)
    opt = torch.optim.AdamW(net.parameters(), lr=cfg.lr, weight_decay=cfg.weight_decay)
    sched = torch.optim.lr_scheduler.CosineAnnealingLR(opt, cfg.epochs)

    def log_f_plus_p(x):
        z = net(x)[:, 0]
        return torch.logaddexp(z, torch.full_like(z, log_p))

    rules = []
    if cfg.albedo_weight > 0:
        for _ in range(TRAIN_SHIFTS):
            ang, w, g = albedo_quadrature(**TRAIN_QUADRATURE, shift=rng.random(2))
            rules.append((torch.from_numpy(encode_reciprocal(*ang.T, cfg.fourier).astype(
                np.float32)), torch.from_numpy(w.astype(np.float32)), torch.from_numpy(g)))
        n_g = len(TRAIN_QUADRATURE["theta_i_deg"])
    best, best_state, log = math.inf, None, []
    for epoch in range(cfg.epochs):
        net.train()
        opt.zero_grad()
        d = log_f_plus_p(X[fit]) - T[fit]
        loss = tf.smooth_l1_loss(d, torch.zeros_like(d), beta=cfg.huber_beta)
        if rules:
            qx, qw, qg = rules[epoch % len(rules)]
            a = torch.zeros(n_g).index_add(0, qg, qw * torch.exp(net(qx)[:, 0]))
            loss = loss + cfg.albedo_weight * torch.relu(a - 1).pow(2).mean()
        loss.backward()
        opt.step()
        sched.step()
        if epoch % cfg.check_every == 0 or epoch == cfg.epochs - 1:
            with torch.no_grad():
                ref = fit if n_val == 0 else val
                v = float(((log_f_plus_p(X[ref]) - T[ref]) ** 2).mean())
            if v < best:
                best, best_state = v, {k: t.clone() for k, t in net.state_dict().items()}
            if epoch % 200 == 0:
                log.append((epoch, float(loss.detach()), v))
        if epoch_done is not None:
            epoch_done(epoch + 1)
    net.load_state_dict(best_state)
    net.eval()
    return net, {"epochs_run": cfg.epochs, "best_val_loss": best, "loss_log": log,
                 "loss_floor_per_sr": p}
