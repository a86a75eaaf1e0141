"""Kinds ``nn`` and ``lstm``: the paper's black-box baselines (no physics, no φ)."""
from __future__ import annotations

import torch
from torch import nn

from deapull.surrogate.data import Transitions
from deapull.surrogate.models.base import InputRange, NativeKernel, Normalisation, Surrogate, mlp, mlp_params
from deapull.surrogate.models.registry import register
from deapull.surrogate.phi import Phi


@register
class NNBaseline(Surrogate):
    """Black box s' = s + σ_Δs · MLP((s, a) normalised): no physics, no φ."""

    kind = "nn"
    label = "NN"

    def __init__(self, norm: Normalisation, input_range: InputRange, hidden: int = 128, layers: int = 3):
        super().__init__(norm, input_range, {"hidden": hidden, "layers": layers})
        self.net = mlp(4, hidden, layers, 2)

    def forward(self, s: torch.Tensor, a: torch.Tensor) -> torch.Tensor:
        return s + self.ds_std * self.net(self.normalised_inputs(s, a))

    def step(self, s, a, memory=None, phi: Phi | None = None):
        return self(s, a), None, None

    def training_loss(self, batch: Transitions) -> torch.Tensor:
        target = (batch.s_next - batch.s) / self.ds_std
        return ((self.net(self.normalised_inputs(batch.s, batch.a)) - target) ** 2).mean()

    def native_kernel(self, phi: Phi | None = None) -> NativeKernel:
        """``deapull_rollout_nn``: norm = in_mean, in_std, ds_std."""
        n_layers, sizes, params = mlp_params(self.net)
        norm = self.buffer_values("in_mean", "in_std", "ds_std")
        return NativeKernel("deapull_rollout_nn", (n_layers, sizes, params, norm), forces=False)


@register
class LSTMBaseline(Surrogate):
    """Black box s' = s + σ_Δs · head(LSTM over the last ``window`` normalised (s, a) pairs).

    The window is re-read at every step (an ``window``-step recurrence, the paper's 8);
    at the start of a run it is padded by repeating the first pair.
    """

    kind = "lstm"
    label = "LSTM"

    def __init__(self, norm: Normalisation, input_range: InputRange, hidden: int = 128, window: int = 8):
        super().__init__(norm, input_range, {"hidden": hidden, "window": window})
        self.window = window
        self.lstm = nn.LSTM(4, hidden, batch_first=True)
        self.head = nn.Linear(hidden, 2)

    @classmethod
    def training_hparams(cls, config, train_sets: list) -> dict:
        return {"hidden": config.hidden, "window": config.window}

    def increment(self, window: torch.Tensor) -> torch.Tensor:
        """Normalised state change from a window (B, W, 4) of raw (x, u, V, Δt)."""
        out, _ = self.lstm((window - self.in_mean) / self.in_std)
        return self.head(out[:, -1])

    def init_memory(self, s0, a0):
        return torch.cat([s0, a0], dim=-1).unsqueeze(1).expand(-1, self.window - 1, -1)

    def step(self, s, a, memory=None, phi: Phi | None = None):
        if memory is None:
            memory = self.init_memory(s, a)
        window = torch.cat([memory, torch.cat([s, a], dim=-1).unsqueeze(1)], dim=1)
        return s + self.ds_std * self.increment(window), None, window[:, 1:]

    def training_loss(self, batch: Transitions) -> torch.Tensor:
        target = (batch.s_next - batch.s) / self.ds_std
        return ((self.increment(batch.window) - target) ** 2).mean()

    def native_kernel(self, phi: Phi | None = None) -> NativeKernel:
        """``deapull_rollout_lstm``: LSTM weights in torch's layout, then the head;
        norm = in_mean, in_std, ds_std."""
        lstm = self.lstm
        params = torch.cat([t.detach().cpu().float().reshape(-1) for t in (
            lstm.weight_ih_l0, lstm.weight_hh_l0, lstm.bias_ih_l0, lstm.bias_hh_l0, self.head.weight,
            self.head.bias)]).numpy()
        return NativeKernel("deapull_rollout_lstm", (lstm.hidden_size, self.window, params,
                                                     self.buffer_values("in_mean", "in_std", "ds_std")), forces=False)
