"""The feasible set a constrained sampler has learned: P(success | xi) from the evidence rows.

`SuccessClassifier` is a small MLP (logistic output) fitted to the 0/1 rows of an `SignalMemory`, in
the unit box, each row's loss weighted (GoFlow passes `SignalMemory.design_weights`, which make the
rows count as a uniform design would, whichever protocol drew them). Each `fit` continues from
the previous parameters (fresh Adam, a fixed number of steps), so the estimate sharpens as rows
accumulate. Minibatches hold half successes and half failures, and each half's loss is scaled by
its class's total weight: the steps estimate the weighted loss, and a set of 0.3 % of the box is
seen in every step. Against the k-nearest-neighbour vote of `SignalMemory` it draws a smooth boundary
that does not erode with the level and does not fray in 3-D and 6-D (measured in
docs/learning.md#sampler-quality-on-known-feasible-sets-issue-21).

The parameters are plain tensors; `state_dict` is JSON-serializable and a resumed run continues
from exactly the same classifier.
"""

from __future__ import annotations

import copy
from collections.abc import Mapping
from typing import Any

import numpy as np
import torch
import torch.nn.functional as F
from numpy.typing import NDArray

from goflow_common.errors import InputError
from learning.samplers.signal_memory import SignalMemory

__all__ = ["SuccessClassifier"]

_CHUNK = 65536
FIT_LR = 3e-3  # Adam's learning rate in every fit
FIRST_FIT_FACTOR = 10  # the first fit starts from scratch: this many times the steps of one that continues
AVERAGE_DECAY = 0.99  # per step: the average spans about the last 100 steps, one GoFlow update's fit


class SuccessClassifier:
    """P(success | xi) on the unit box: an MLP with SiLU layers and a logistic output.

    Arguments:
        dim: the parameter dimension.
        hidden: layer sizes.
        seed: the initialization's seed.
    """

    def __init__(self, dim: int, hidden: tuple[int, ...] = (64, 64), seed: int = 0) -> None:
        self.dim, self.hidden = dim, tuple(hidden)
        layers: list[torch.nn.Module] = []
        width = dim
        with torch.random.fork_rng(devices=[]):
            torch.manual_seed(seed)
            for h in self.hidden:
                layers += [torch.nn.Linear(width, h), torch.nn.SiLU()]
                width = h
            layers.append(torch.nn.Linear(width, 1))
        self._net = torch.nn.Sequential(*layers)
        # what `probability` reads: an exponential moving average of the parameters over the steps,
        # so the boundary does not jitter with the last minibatches (each fit's fresh Adam jolts the
        # parameters by about lr in its first steps)
        self._average = copy.deepcopy(self._net).requires_grad_(False)
        self.fitted = False

    @staticmethod
    def _logit(net: torch.nn.Module, x_unit: torch.Tensor) -> torch.Tensor:
        return net(x_unit * 2.0 - 1.0).squeeze(-1)

    def fit(
        self,
        xi_unit: NDArray[np.float64],
        success: NDArray[np.float64],
        weights: NDArray[np.float64],
        *,
        steps: int,
        batch: int,
        lr: float,
        gen: torch.Generator,
    ) -> float | None:
        """`steps` Adam steps of logistic regression on the rows, each row's loss weighted by
        `weights` (positive, shape (n,)); returns the last loss, or None (nothing fitted) while the
        rows hold only one class.

        Each minibatch holds `batch` / 2 successes and as many failures, drawn in proportion to
        their weights, and the two halves' losses are scaled by their classes' total weights, so
        the steps estimate the weighted loss with both classes seen in every step."""
        success = np.asarray(success) >= 0.5
        weights = np.asarray(weights, dtype=np.float64)
        good, bad = np.flatnonzero(success), np.flatnonzero(~success)
        if not len(good) or not len(bad):
            return None
        x = torch.as_tensor(np.asarray(xi_unit), dtype=torch.float32)
        x_good, x_bad = x[good], x[bad]
        w_good, w_bad = torch.as_tensor(weights[good]), torch.as_tensor(weights[bad])
        share = float(w_good.sum() / (w_good.sum() + w_bad.sum()))
        half = max(batch // 2, 1)
        target = torch.cat([torch.ones(half), torch.zeros(half)])
        scale = torch.cat([torch.full((half,), share), torch.full((half,), 1.0 - share)]) * 2.0
        optimizer = torch.optim.Adam(self._net.parameters(), lr=lr)
        loss = torch.zeros(())
        for _ in range(steps):
            xb = torch.cat(
                [
                    x_good[torch.multinomial(w_good, half, replacement=True, generator=gen)],
                    x_bad[torch.multinomial(w_bad, half, replacement=True, generator=gen)],
                ]
            )
            loss = (
                scale * F.binary_cross_entropy_with_logits(self._logit(self._net, xb), target, reduction="none")
            ).mean()
            optimizer.zero_grad(set_to_none=True)
            loss.backward()
            optimizer.step()
            with torch.no_grad():
                if not self.fitted:  # the first step of the first fit starts the average
                    self._average.load_state_dict(self._net.state_dict())
                    self.fitted = True
                for avg, p in zip(self._average.parameters(), self._net.parameters()):
                    avg.lerp_(p, 1.0 - AVERAGE_DECAY)
        return float(loss.detach())

    def fit_evidence(self, evidence: SignalMemory, *, steps: int, batch: int, gen: torch.Generator) -> float | None:
        """One sampler update's fit to every row of `evidence` (0/1 scaled signals), each weighted
        as a uniform design would count it (`SignalMemory.design_weights`): `steps` Adam steps at
        `FIT_LR`, `FIRST_FIT_FACTOR` times as many while nothing is fitted yet. Returns `fit`'s loss."""
        steps = steps * (1 if self.fitted else FIRST_FIT_FACTOR)
        return self.fit(
            evidence.xi,
            evidence.scaled_signal(),
            evidence.design_weights(),
            steps=steps,
            batch=batch,
            lr=FIT_LR,
            gen=gen,
        )

    def probability(self, xi_unit: NDArray[np.float64] | torch.Tensor) -> NDArray[np.float64]:
        """P(success) at points of the unit box, shape (n,) (zeros before the first fit)."""
        x = torch.as_tensor(np.asarray(xi_unit), dtype=torch.float32).reshape(-1, self.dim)
        if not self.fitted:
            return np.zeros(len(x))
        with torch.no_grad():
            logits = (
                torch.cat([self._logit(self._average, x[i : i + _CHUNK]) for i in range(0, len(x), _CHUNK)])
                if len(x)
                else x[:, 0]
            )
        return torch.sigmoid(logits.double()).numpy()

    def state_dict(self) -> dict[str, Any]:
        """JSON-serializable parameters."""
        return {
            "fitted": self.fitted,
            "params": {k: v.flatten().tolist() for k, v in self._net.state_dict().items()},
            "average": {k: v.flatten().tolist() for k, v in self._average.state_dict().items()},
        }

    def load_state_dict(self, state: Mapping[str, Any]) -> None:
        """Restore what `state_dict` saved (InputError if the shapes do not fit this classifier)."""
        own = self._net.state_dict()
        try:
            params = {k: torch.tensor(state["params"][k], dtype=torch.float32).reshape(v.shape) for k, v in own.items()}
            # states saved before the average existed read their last parameters
            saved = state.get("average", state["params"])
            average = {k: torch.tensor(saved[k], dtype=torch.float32).reshape(v.shape) for k, v in own.items()}
            fitted = bool(state["fitted"])
        except (KeyError, TypeError, RuntimeError, ValueError) as exc:
            raise InputError(
                f"success classifier state: {exc!r}; expected the state_dict of a {self.hidden} "
                f"classifier on {self.dim} parameters"
            ) from exc
        if not all(torch.isfinite(v).all() for v in [*params.values(), *average.values()]):
            raise InputError("success classifier state: non-finite parameters; expected finite ones")
        self._net.load_state_dict(params)
        self._average.load_state_dict(average)
        self.fitted = fitted
