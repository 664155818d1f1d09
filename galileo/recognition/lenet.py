"""LeNet (LeCun et al. 1998) reading an object's mass and friction from one image patch.

Input: a 3 x 32 x 32 RGB patch (`galileo.vision.patch`: a 0.20 m square around the object,
so its size in metres shows), scaled to (x / 255 - 0.5) / 0.25. Layers, as LeNet-5: conv
5x5 (6) - ReLU - max-pool 2 - conv 5x5 (16) - ReLU - max-pool 2 - fully connected 400 -> 120
- ReLU - fully connected 120 -> 4. The four outputs are a Gaussian per quantity (mean and
log-variance) for

* mass on the log-normalised scale: y = ln(m / m_lo) / ln(m_hi / m_lo), (m_lo, m_hi) the
  scenario's `recognition_mass_range_kg` (the ramp's: 0.005 kg -> 0, 0.2 kg -> 1, its
  catalogue's lightest and heaviest objects rounded; `MASS_RANGE_KG`), and
* the friction coefficient itself.

Loss: the Gaussian negative log-likelihood over the labels a patch has (a video without a
mass label still teaches friction). A model is an ensemble of `MEMBERS` such networks from
different seeds; its prediction is the ensemble's mixture (mean of means; variance = mean of
variances + variance of means), so it says how unsure it is (Lakshminarayanan et al. 2017).
"""
from __future__ import annotations

import math
from dataclasses import dataclass

import contextlib

import numpy as np

from ..progress import tqdm
from ..model import Scenario

MASS_RANGE_KG = Scenario.recognition_mass_range_kg   # the default scale (the ramp's)
MEMBERS = 5            # ensemble size
EPOCHS = 60
BATCH = 32
LEARNING_RATE = 2e-3
WEIGHT_DECAY = 1e-4
SHIFT_PX = 2           # augmentation: random shifts up to this many pixels
JITTER = 0.1           # augmentation: brightness and contrast within +-10%
LOGVAR_RANGE = (-9.0, 2.0)   # the predicted log-variances are clamped here
  # log volume input: (ln V - centre) / scale (about 1 cm^3 to 1 l -> -2.5..2)


def mass_to_y(m_kg, rng=MASS_RANGE_KG):
    return np.log(np.asarray(m_kg, float) / rng[0]) / math.log(rng[1] / rng[0])


def y_to_mass(y, rng=MASS_RANGE_KG):
    return rng[0] * np.exp(np.asarray(y, float) * math.log(rng[1] / rng[0]))


def _torch():
    import torch

    return torch


def net():
    torch = _torch()
    from torch import nn

    class LeNet(nn.Module):
        def __init__(self):
            super().__init__()
            self.features = nn.Sequential(nn.Conv2d(3, 6, 5), nn.ReLU(), nn.MaxPool2d(2),
                                          nn.Conv2d(6, 16, 5), nn.ReLU(), nn.MaxPool2d(2))
            self.head = nn.Sequential(nn.Linear(16 * 5 * 5, 120), nn.ReLU(), nn.Linear(120, 4))

        def forward(self, x):
            out = self.head(self.features(x).flatten(1))
            mu = out[:, 0::2]
            logvar = torch.clamp(out[:, 1::2], *LOGVAR_RANGE)
            return mu, logvar

    return LeNet()


def to_input(patches_u8: np.ndarray):
    """(N, 32, 32, 3) uint8 -> (N, 3, 32, 32) float tensor."""
    torch = _torch()
    x = np.asarray(patches_u8, np.float32).transpose(0, 3, 1, 2) / 255.0
    return torch.from_numpy((x - 0.5) / 0.25)


def _augment(x, gen):
    torch = _torch()
    n = x.shape[0]
    pad = torch.nn.functional.pad(x, (SHIFT_PX,) * 4, mode="replicate")
    dx = torch.randint(0, 2 * SHIFT_PX + 1, (n,), generator=gen)
    dy = torch.randint(0, 2 * SHIFT_PX + 1, (n,), generator=gen)
    c, h, w = x.shape[1:]
    iy = (torch.arange(h)[None, :] + dy[:, None])[:, None, :, None]
    ix = (torch.arange(w)[None, :] + dx[:, None])[:, None, None, :]
    out = pad[torch.arange(n)[:, None, None, None], torch.arange(c)[None, :, None, None], iy, ix]
    gain = 1 + JITTER * (2 * torch.rand((n, 1, 1, 1), generator=gen) - 1)
    bias = JITTER * (2 * torch.rand((n, 1, 1, 1), generator=gen) - 1) / 0.25
    return out * gain + bias


@dataclass
class Trained:
    states: list            # one state_dict (name -> numpy array) per member
    history: list           # per member: the mean training loss per epoch


def train(patches_u8: np.ndarray, y: np.ndarray, *, seed: int = 0, members: int = MEMBERS, epochs: int = EPOCHS,
          progress: bool = True, desc: str = "training") -> Trained:
    """Train the ensemble on patches (N, 32, 32, 3) and labels y (N, 2): [mass on the
    log-normalised scale, friction], NaN where a patch has no label."""
    torch = _torch()
    with one_thread():
        return _train(torch, patches_u8, y, seed, members, epochs, progress, desc)


@contextlib.contextmanager
def one_thread():
    """Torch on one thread for the block (the caller's number after): these networks are
    tiny, and a second thread only waits on the first (20x slower steps measured on 2 busy
    cores). Yields torch."""
    torch = _torch()
    before = torch.get_num_threads()
    torch.set_num_threads(1)
    try:
        yield torch
    finally:
        torch.set_num_threads(before)


def mixture(means: np.ndarray, variances: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """An equal-weight mixture's mean and variance over axis 0 (ensemble members, or several
    readings of one object): mean of means; mean of variances + variance of means."""
    means, variances = np.asarray(means, float), np.asarray(variances, float)
    return means.mean(0), variances.mean(0) + means.var(0)


def _train(torch, patches_u8, y, seed, members, epochs, progress, desc) -> Trained:
    x_all = to_input(patches_u8)
    y_all = torch.from_numpy(np.asarray(y, np.float32))
    have = ~torch.isnan(y_all)
    y0 = torch.nan_to_num(y_all)
    n = len(x_all)
    if n == 0 or not bool(have.any()):
        from ..errors import GalileoError

        raise GalileoError("no labelled patches to train on")
    states, history = [], []
    total = members * epochs
    with tqdm(total=total, desc=desc, unit="epoch", disable=not progress) as bar:
        for m in range(members):
            torch.manual_seed(seed * 1000 + m)
            gen = torch.Generator().manual_seed(seed * 1000 + m)
            model = net()
            opt = torch.optim.Adam(model.parameters(), lr=LEARNING_RATE, weight_decay=WEIGHT_DECAY)
            sched = torch.optim.lr_scheduler.CosineAnnealingLR(opt, epochs)
            losses = []
            for _ in range(epochs):
                perm = torch.randperm(n, generator=gen)
                tot, cnt = 0.0, 0
                model.train()
                for i in range(0, n, BATCH):
                    idx = perm[i:i + BATCH]
                    mu, logvar = model(_augment(x_all[idx], gen))
                    h = have[idx]
                    nll = 0.5 * (logvar + (y0[idx] - mu) ** 2 / torch.exp(logvar))
                    loss = (nll * h).sum() / h.sum().clamp(min=1)
                    opt.zero_grad()
                    loss.backward()
                    opt.step()
                    tot += float(loss.detach()) * len(idx)
                    cnt += len(idx)
                sched.step()
                losses.append(tot / max(cnt, 1))
                bar.update()
            states.append({k: v.detach().numpy().copy() for k, v in model.state_dict().items()})
            history.append(losses)
    return Trained(states, history)


def predict(states: list, patches_u8: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Mean (N, 2) and standard deviation (N, 2) of the ensemble's mixture per patch."""
    torch = _torch()
    x = to_input(patches_u8)
    mus, vars_ = [], []
    with torch.no_grad(), one_thread():
        for st in states:
            model = net()
            model.load_state_dict({k: torch.from_numpy(np.asarray(v, np.float32)) for k, v in st.items()})
            model.eval()
            mu, logvar = model(x)
            mus.append(mu.numpy())
            vars_.append(np.exp(logvar.numpy()))
    mean, var = mixture(np.stack(mus), np.stack(vars_))
    return mean, np.sqrt(var)


def pool(mean: np.ndarray, sd: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Several patches of one object -> one Gaussian per quantity (the mixture's moments)."""
    m, var = mixture(mean, sd ** 2)
    return m, np.sqrt(var)
