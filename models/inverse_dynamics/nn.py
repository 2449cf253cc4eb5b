"""Neural-network inverse-dynamics estimator (the thesis's data-driven baseline, section 3.4.1).

A fully connected network ``[q, qd, qdd] (3n) -> H -> H -> n`` (two hidden layers of
``H = 400`` units, ``tanh``; the thesis uses sigmoids, 600 units for the UR10), inputs and
outputs standardised with the training statistics, mean-squared-error loss, Adam with
mini-batches, and early stopping: a random ``validation_fraction`` of the training rows is
held out, training stops after ``patience`` epochs without improvement of the validation MSE
and the best weights are restored.

``predict`` returns ``(mean, None)``: a point estimate, no variance.
"""

from __future__ import annotations

import copy

import numpy as np
import torch
from numpy.typing import NDArray
from torch import nn

from mcpilco.models.inverse_dynamics.base import InverseDynamicsEstimator
from mcpilco.models.inverse_dynamics.inputs import JointStates

FloatArray = NDArray[np.float64]

__all__ = ["NNEstimator", "mlp"]

ACTIVATIONS = {"tanh": nn.Tanh, "relu": nn.ReLU, "sigmoid": nn.Sigmoid}


def mlp(d_in: int, d_out: int, hidden: int, layers: int, activation: str) -> nn.Sequential:
    """``layers`` hidden layers of ``hidden`` units with ``activation``, linear output."""
    if activation not in ACTIVATIONS:
        raise ValueError(f"activation must be one of {sorted(ACTIVATIONS)}, got {activation!r}")
    mods: list[nn.Module] = []
    width = d_in
    for _ in range(layers):
        mods += [nn.Linear(width, hidden), ACTIVATIONS[activation]()]
        width = hidden
    mods.append(nn.Linear(width, d_out))
    return nn.Sequential(*mods)


class NNEstimator(InverseDynamicsEstimator):
    """MLP regression of the joint torques with early stopping.

    Args:
        n_joints: ``n`` (``None``: from the data).
        hidden: units per hidden layer.
        layers: hidden layers.
        activation: ``"tanh"``, ``"relu"`` or ``"sigmoid"``.
        lr: Adam learning rate.
        weight_decay: Adam weight decay.
        batch_size: mini-batch size.
        max_epochs: epoch cap.
        patience: epochs without validation improvement before stopping.
        validation_fraction: share of the training rows held out for early stopping
            (at least one row; with fewer than 10 rows no hold-out, ``max_epochs`` epochs).
        seed: seed of the initial weights, the split and the batch order.
        dtype: parameter dtype (float32 is faster on CPU).

    Fitted attributes: ``net_``, ``epochs_`` (epochs run), ``best_val_mse_`` (standardised).
    """

    name = "NN"

    def __init__(
        self,
        n_joints: int | None = None,
        *,
        hidden: int = 400,
        layers: int = 2,
        activation: str = "tanh",
        lr: float = 1e-3,
        weight_decay: float = 0.0,
        batch_size: int = 64,
        max_epochs: int = 2000,
        patience: int = 100,
        validation_fraction: float = 0.15,
        seed: int = 0,
        dtype: torch.dtype = torch.float32,
    ) -> None:
        super().__init__(n_joints)
        if activation not in ACTIVATIONS:
            raise ValueError(f"activation must be one of {sorted(ACTIVATIONS)}, got {activation!r}")
        if not 0.0 <= validation_fraction < 1.0:
            raise ValueError(f"validation_fraction must be in [0, 1), got {validation_fraction}")
        self.hidden, self.layers, self.activation = hidden, layers, activation
        self.lr, self.weight_decay = lr, weight_decay
        self.batch_size, self.max_epochs, self.patience = batch_size, max_epochs, patience
        self.validation_fraction, self.seed, self.dtype = validation_fraction, seed, dtype

    def _fit(self, states: JointStates, y: FloatArray) -> None:
        gen = torch.Generator().manual_seed(self.seed)
        torch.manual_seed(self.seed)
        x = states.stacked()
        self.x_mean_, self.x_scale_ = x.mean(0), x.std(0)
        self.x_scale_[self.x_scale_ == 0] = 1.0
        self.y_mean_, self.y_scale_ = y.mean(0), y.std(0)
        self.y_scale_[self.y_scale_ == 0] = 1.0
        xt = torch.as_tensor((x - self.x_mean_) / self.x_scale_, dtype=self.dtype)
        yt = torch.as_tensor((y - self.y_mean_) / self.y_scale_, dtype=self.dtype)
        n_rows = xt.shape[0]
        perm = torch.randperm(n_rows, generator=gen)
        n_val = int(round(self.validation_fraction * n_rows)) if n_rows >= 10 else 0
        n_val = max(n_val, 1) if self.validation_fraction > 0 and n_rows >= 10 else n_val
        val, train = perm[:n_val], perm[n_val:]
        net = mlp(xt.shape[1], yt.shape[1], self.hidden, self.layers, self.activation)
        net = net.to(self.dtype)
        opt = torch.optim.Adam(net.parameters(), lr=self.lr, weight_decay=self.weight_decay)
        best, best_state, stale, epoch = float("inf"), None, 0, 0
        xtr, ytr = xt[train], yt[train]
        for epoch in range(1, self.max_epochs + 1):  # noqa: B007 - epoch kept below
            order = torch.randperm(xtr.shape[0], generator=gen)
            for start in range(0, xtr.shape[0], self.batch_size):
                idx = order[start : start + self.batch_size]
                opt.zero_grad(set_to_none=True)
                loss = (net(xtr[idx]) - ytr[idx]).pow(2).mean()
                loss.backward()
                opt.step()
            if n_val == 0:
                continue
            with torch.no_grad():
                v = float((net(xt[val]) - yt[val]).pow(2).mean())
            if v < best - 1e-12:
                best, best_state, stale = v, copy.deepcopy(net.state_dict()), 0
            else:
                stale += 1
                if stale >= self.patience:
                    break
        if best_state is not None:
            net.load_state_dict(best_state)
        if not np.isfinite(best) and n_val > 0:
            raise ValueError("the network's validation loss is not finite; lower lr")
        self.net_ = net.eval()
        self.epochs_ = epoch
        self.best_val_mse_ = best

    def _predict(self, states: JointStates) -> tuple[FloatArray, None]:
        xt = torch.as_tensor((states.stacked() - self.x_mean_) / self.x_scale_, dtype=self.dtype)
        with torch.no_grad():
            out = self.net_(xt).double().numpy()
        return out * self.y_scale_ + self.y_mean_, None
