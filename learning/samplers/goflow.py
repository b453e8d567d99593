"""GoFlow: flow-based maximum-entropy domain randomization (Curtis et al., ICML 2025).

The sampler is a neural spline flow (zuko NSF: 3 autoregressive transforms, hidden (64, 64), 8
bins) over the parameter box, mapped affinely to zuko's spline domain [-5, 5]^d ("box coordinates"
below). `update(xi, signal)` takes K guarded Adam steps (lr 1e-3, K = 100) towards the optimum of
the objective that `config.mode` names:

- "entropy": max E_p[r] + alpha H(p) over the box, r the signal scaled onto [0, 1]
  (`signal_range`, default the range seen so far). Optimum p*(xi) ~ exp(r(xi) / alpha).
- "constrained": max H(p) subject to E_p[success] >= 1 - delta, for 0/1 success signals. Optimum
  (1 - delta) x uniform on the feasible set + delta x uniform on the rest of the box.
- "paper": the authors' update, loss -(1/B) sum_i log q(y_i) R_i - alpha H_hat + beta KL_hat on the
  batch alone, R_i the batch-standardized returns (`standardize_returns`), H_hat the entropy from
  fresh uniform samples. It weights log q by returns whatever distribution drew the batch, pushes
  failures' density down without bound, and forgets earlier batches: it does not reach the optimum
  of its own objective (docs/learning.md#goflow-modes).

The entropy and constrained modes keep the newest `memory` evaluated rows (`SignalMemory`) and estimate
the signal anywhere as a k-nearest-neighbour mean, which does not depend on which protocol drew the
rows. The constrained mode estimates its feasible set F-hat = {P(success) >= level} with a success
classifier fitted to the rows, each weighted as a uniform design would count it
(`learning.samplers.feasibility`; or the k-NN vote, `feasible_model="knn"`), and by default
samples the flow truncated to F-hat with mass 1 - delta plus delta uniform on the rest of the box
(`truncate`): the sampler's edge is then F-hat's, not the flow's rounded one; `floor` (0.2) draws
that share of the mass in F-hat uniformly on F-hat, a floor under the flow's density there. The level starts at
`feasible_level` and follows the constraint by dual ascent: each batch, before it joins the
evidence, is a held-out test of F-hat, and the level rises while more than `leak_target` of the
sampler's mass in F-hat fails and falls while less does.

Each update draws a proposal (uniform on the box, the current flow, and Gaussians around the rows
that succeeded) with its exact mixture density, weights the draws by target / proposal
(self-normalized), and fits the flow by maximum likelihood on draws resampled by those weights:
a forward KL(p* || q) fit, which covers every component of the target instead of collapsing onto
one. `beta` > 0 adds KL(q_old || q) on the old flow's draws as a trust region (default 0).

Steps with a non-finite loss or gradient are skipped, gradients are clipped at norm 1, and the flow
reverts to its pre-update parameters if any parameter ends non-finite (all reported in the
returned diagnostics).

Conventions: `sample` draws exactly from the flow truncated to the box (with `truncate`, from the
mixture above: flow draws in F-hat by rejection, uniform ones outside); `log_prob` is that
density in parameter units, normalized over the box (-inf outside; with `truncate` the flow's
mass in F-hat is a fixed-seed Monte Carlo estimate from 16384 draws, refreshed at each update and
load); `entropy()` is -E_p[log p] in parameter units from a fixed-seed set of the sampler's draws
(deterministic). The flow
starts as the identity on a N(0, 2.5^2) base in box coordinates (broad, close to uniform). An
update depends only on the flow, the batch and (config.seed, update count), so a run resumed from
a `state_dict` reproduces the uninterrupted one.

Derivation (box invariance and exact normalization, the identity initialization and base scale,
the entropy estimators): docs/learning.md#goflow; sample sizes: docs/learning.md, "Departures
from the paper".

Modules: `goflow_config` (the settings), `spline_flow` (the flow on the box), `goflow_proposal`
and `goflow_objectives` (what an update fits, by mode), `feasible_gate` (F-hat: the truncation and
its level's dual ascent), `evidence` and `feasibility` (the rows kept, the success classifier).

References: Curtis et al., "Flow-based Domain Randomization for Learning and Sequencing Robotic
Skills", ICML 2025 (arXiv:2502.01800), and the authors' code github.com/aidan-curtis/goflow;
Durkan et al., "Neural Spline Flows", NeurIPS 2019; zuko (github.com/probabilists/zuko).
"""

from __future__ import annotations

import math
import time
from collections.abc import Mapping
from typing import Any

import numpy as np
import torch
from numpy.typing import ArrayLike, NDArray

from assembly.params import ParamSpace
from assembly.samplers import check_sample_args, check_sampler_args, check_state_dict, check_update_inputs
from goflow_common.checks import check_number
from goflow_common.config import config_with_overrides
from goflow_common.errors import InputError
from learning.samplers.signal_memory import SignalMemory
from learning.samplers.feasibility import SuccessClassifier
from learning.samplers.feasible_gate import (
    GATE_DRAWS,
    GATE_SEED,
    Gate,
    estimate_gate,
    follow_constraint,
    sample_truncated,
    truncated_log_density,
)
from learning.samplers.goflow_config import GoFlowConfig, goflow_config_of
from learning.samplers.goflow_objectives import Loss, descend, fit_loss, paper_loss, target_weights
from learning.samplers.goflow_proposal import proposal
from learning.samplers.gradient_update import standardize_returns, update_diagnostics
from learning.samplers.spline_flow import (
    BOX_BOUND,
    box_to_unit,
    draw_in_box,
    flow_log_q,
    identity_flow,
    log_box_mass,
    tensor_from_json,
    tensor_to_json,
    uniform_box,
)

__all__ = ["GoFlowSampler"]


class GoFlowSampler:
    """Flow-based maximum-entropy DR sampler (GoFlow) on the Sampler protocol.

    Arguments:
        space: the parameter box.
        success_threshold: J_T (kept for reference: GoFlow learns from the signal it is given).
        config: weights (alpha, beta), architecture and update settings: a GoFlowConfig, a mapping
            of its fields, or None (defaults); keyword `overrides` are its fields, applied last.
    """

    def __init__(
        self,
        space: ParamSpace,
        success_threshold: float | None = None,
        config: GoFlowConfig | Mapping[str, Any] | None = None,
        **overrides: Any,
    ) -> None:
        self.success_threshold = check_sampler_args(space, success_threshold, "GoFlowSampler")
        self.space = space
        self.config = config_with_overrides(GoFlowConfig, config, overrides, "GoFlowSampler")
        self.n_updates = 0
        d = space.dim
        self._low = space.low
        self._width = space.high - space.low
        self._centre = space.center()
        self._half_scale = self._width / (2.0 * BOX_BOUND)  # parameter units per box unit
        # log Z: base mass inside [-5, 5]^d, exact and constant (the box is invariant under the flow)
        self._log_z = log_box_mass(d, self.config.base_scale)
        self._log_jac = -float(np.sum(np.log(self._half_scale)))  # log|dy/dxi|
        self._log_box = d * math.log(2.0 * BOX_BOUND)  # log volume of the box [-5, 5]^d
        cfg = self.config
        self._flow = identity_flow(d, cfg.transforms, cfg.hidden_features, cfg.bins, cfg.base_scale, cfg.seed)
        self._entropy_cache: float | None = None
        self._evidence = SignalMemory(
            d, self.config.memory, self.config.neighbours, self.config.signal_range, self.config.boundary_memory
        )
        self._classifier = self._make_classifier(self.config)
        # the truncation to F-hat (constrained mode): (log flow mass in F-hat, log box share outside
        # it, log box share inside it for the floor), or None while the sampler is the flow alone
        self._gate: Gate | None = None
        self._level = self.config.feasible_level  # F-hat's level now (constrained mode; see GoFlowConfig)

    @property
    def alpha(self) -> float:
        """Entropy weight (config.alpha)."""
        return self.config.alpha

    @property
    def beta(self) -> float:
        """KL trust-region weight (config.beta)."""
        return self.config.beta

    def _make_classifier(self, config: GoFlowConfig) -> SuccessClassifier | None:
        """The success classifier behind F-hat (constrained mode with feasible_model "classifier")."""
        if config.mode != "constrained" or config.feasible_model != "classifier":
            return None
        return SuccessClassifier(self.space.dim, config.classifier_layers(self.space.dim), config.seed)

    # -- coordinates -----------------------------------------------------------------------------

    def _to_box(self, xi: NDArray[np.float64]) -> NDArray[np.float64]:
        return (xi - self._centre) / self._half_scale

    def _from_box(self, y: NDArray[np.float64]) -> NDArray[np.float64]:
        return self._centre + y * self._half_scale

    def _log_q(self, y: torch.Tensor) -> torch.Tensor:
        """Unnormalized flow log density in box coordinates, without gradients, chunked."""
        return flow_log_q(self._flow, y)

    def _draw_box(self, n: int, gen: torch.Generator) -> torch.Tensor:
        """n draws of the flow truncated to the box, in box coordinates (float32, shape (n, d))."""
        return draw_in_box(self._flow, n, self.space.dim, self.config.base_scale, self.config.max_redraws, gen)

    def _feasible_hat(self, y: torch.Tensor) -> torch.Tensor:
        """Whether box-coordinate points lie in the estimated feasible set F-hat (bool, shape (n,))."""
        u = box_to_unit(y)
        p = self._classifier.probability(u) if self._classifier is not None else self._evidence.estimate(u)
        return torch.as_tensor(p >= self._level)

    def _follow_constraint(self, xi_arr: NDArray[np.float64], ret: NDArray[np.float64]) -> dict[str, float]:
        """One dual-ascent step of F-hat's level (`feasible_gate.follow_constraint`) on a batch F-hat
        has not been fitted to (constrained mode, while the sampler is truncated); what it saw."""
        cfg = self.config
        if cfg.level_step == 0 or self._gate is None:  # the gate exists in the constrained mode alone
            return {}
        y = torch.as_tensor(self._to_box(xi_arr), dtype=torch.float32).clamp(-BOX_BOUND, BOX_BOUND)
        inside = self._feasible_hat(y).numpy()
        if not inside.any():
            return {"heldout_in_feasible": 0.0}
        log_ratio = self._log_p_box(y).numpy() + self._log_box  # sampler / uniform
        self._level, info = follow_constraint(self._level, inside, log_ratio, ret, cfg.level_step, cfg.leak_target)
        return info

    def _refresh_gate(self) -> None:
        """Re-estimate the truncation's shares from fixed-seed draws (deterministic in the flow and
        F-hat); no truncation outside the constrained mode, while F-hat is empty or the whole box,
        or while the flow puts under 1 % of its mass in F-hat."""
        self._gate = None
        if self.config.mode != "constrained" or not self.config.truncate or not len(self._evidence):
            return
        if not np.ptp(self._evidence.signal) > 0:
            return
        gen = torch.Generator().manual_seed(int(self.config.seed) + GATE_SEED)
        y_flow, y_uniform = self._draw_box(GATE_DRAWS, gen), uniform_box(GATE_DRAWS, self.space.dim, gen)
        self._gate = estimate_gate(
            y_flow,
            y_uniform,
            self._feasible_hat,
            lambda y: self._log_q(y) - self._log_z,
            self.config.floor,
            self._log_box,
        )

    def _log_p_box(self, y: torch.Tensor) -> torch.Tensor:
        """The sampler's log density in box coordinates, normalized over the box (float64): the
        truncated flow, or with the truncation (1 - delta) x the flow in F-hat / its mass there, and
        delta x uniform on the rest of the box."""
        lq = (self._log_q(y) - self._log_z).double()
        if self._gate is None:
            return lq
        return truncated_log_density(
            lq, self._feasible_hat(y), self._gate, self.config.delta, self.config.floor, self._log_box
        )

    def _sample_box(self, n: int, gen: torch.Generator) -> torch.Tensor:
        """n draws of the sampler in box coordinates: the flow truncated to the box, or the
        truncated sampler (`feasible_gate.sample_truncated`)."""
        if self._gate is None:
            return self._draw_box(n, gen)
        return sample_truncated(
            n,
            gen,
            self._gate,
            self.config.delta,
            self.config.floor,
            lambda m: self._draw_box(m, gen),
            self._feasible_hat,
            self.space.dim,
            self.config.max_redraws,
        )

    # -- protocol --------------------------------------------------------------------------------

    def sample(self, n: int, rng: np.random.Generator) -> NDArray[np.float64]:
        """n draws from the flow truncated to the box, shape (n, d), parameter units.

        The torch generator is seeded from `rng` (one integer drawn), so the same numpy rng state
        gives the same samples.
        """
        n = check_sample_args(n, rng)
        gen = torch.Generator().manual_seed(int(rng.integers(0, 2**63 - 1)))
        if n == 0:
            return np.zeros((0, self.space.dim))
        y = self._sample_box(n, gen).to(torch.float64).numpy()
        xi = self._from_box(y)
        return np.clip(xi, self._low, self._low + self._width)

    def log_prob(self, xi: ArrayLike) -> NDArray[np.float64]:
        """Log density (parameter units) of the flow truncated to the box and normalized exactly; -inf outside."""
        batch = self.space.as_batch(xi)
        out = np.full(len(batch), -math.inf)
        inside = np.asarray(self.space.contains(batch), dtype=bool)
        if inside.any():
            y = torch.as_tensor(self._to_box(batch[inside]), dtype=torch.float32)
            out[inside] = self._log_p_box(y).numpy() + self._log_jac
        return out

    def entropy(self) -> float:
        """Differential entropy estimate (nats, parameter units) of the truncated flow: -E_p[log p].

        Monte Carlo over a fixed-seed set of `report_samples` flow draws (deterministic in the
        parameters; cached until the next update or load).
        """
        if self._entropy_cache is None:
            gen = torch.Generator().manual_seed(int(self.config.seed) + 7_919)
            y = self._sample_box(self.config.report_samples, gen)
            h_box = -float(self._log_p_box(y).mean())
            self._entropy_cache = h_box - self._log_jac
        return self._entropy_cache

    def update(self, xi: ArrayLike, returns: ArrayLike) -> dict[str, Any]:
        """K Adam steps towards the mode's optimum given this batch (xi, signal); returns diagnostics.

        Raises ValueError for a batch outside the box or a non-finite signal, and InputError for a
        signal outside {0, 1} in constrained mode.
        """
        xi_arr, ret = check_update_inputs(self.space, xi, returns)
        if self.config.mode == "constrained":
            bad = ~np.isin(ret, (0.0, 1.0))
            if bad.any():
                i = int(np.flatnonzero(bad)[0])
                raise InputError(
                    f"update: signal[{i}] = {float(ret[i])!r}; the constrained mode learns from 0/1 successes "
                    "(give sampler_signal='success')"
                )
        if self.config.mode == "paper":
            return self._paper_update(xi_arr, ret)
        return self._fit_update(xi_arr, ret)

    def _update_generator(self) -> torch.Generator:
        """The update's Monte Carlo generator: a function of (config.seed, update count) only."""
        seed = int(np.random.SeedSequence([int(self.config.seed), self.n_updates]).generate_state(1, np.uint64)[0]) >> 1
        return torch.Generator().manual_seed(seed)

    def _descend(self, step_loss: Loss, y_old: torch.Tensor, lq_old: torch.Tensor) -> dict[str, Any]:
        """`goflow_objectives.descend` on `step_loss`; counts the update and adds KL(q_old || q_new)
        on the pre-update flow's draws `y_old` (their unnormalized log densities `lq_old`), after
        any revert."""
        run = descend(self.config, self._flow, step_loss)
        self.n_updates += 1
        self._entropy_cache = None
        run["kl"] = float((lq_old - self._log_q(y_old)).mean()) if len(y_old) else 0.0
        return run

    def _fit_update(self, xi_arr: NDArray[np.float64], ret: NDArray[np.float64]) -> dict[str, Any]:
        """Entropy and constrained modes: remember the batch, then K Adam steps of maximum likelihood
        on draws resampled from the mode's optimum given the evidence (docs/learning.md#goflow-modes)."""
        t0 = time.perf_counter()
        cfg = self.config
        info_level = self._follow_constraint(xi_arr, ret)  # before the batch joins the evidence: held out
        self._evidence.add((xi_arr - self._low) / self._width, ret)
        gen = self._update_generator()
        if self._classifier is not None:
            loss = self._classifier.fit_evidence(
                self._evidence, steps=cfg.classifier_steps, batch=cfg.fit_batch, gen=gen
            )
            info_classifier = {"classifier_loss": math.nan if loss is None else loss}
        else:
            info_classifier = {}
        y, log_m, lq_prop, n = proposal(
            cfg.proposal_samples,
            self.space.dim,
            gen,
            self._evidence,
            lambda m: self._draw_box(m, gen),
            lambda y: self._log_q(y) - self._log_z,
            self._log_box,
        )
        w, info, outside = target_weights(cfg, self.space.dim, y, log_m, self._evidence, self._feasible_hat)
        y_old, lq_old = y[n : 2 * n], lq_prop[n : 2 * n] + self._log_z  # the pre-update flow's own draws
        ceiling = info.get("log_ceiling", 0.0) + self._log_z  # in the flow's unnormalized log density
        run = self._descend(fit_loss(cfg, self._flow, gen, y, w, outside, ceiling, y_old, lq_old), y_old, lq_old)
        self._refresh_gate()
        if self._gate is not None:
            info["flow_mass_in_feasible"] = math.exp(self._gate.log_accept)
        if cfg.mode == "constrained":
            info["feasible_level"] = self._level
        return update_diagnostics(
            ret,
            self.entropy(),
            first=run["first"],
            last=run["last"],
            steps=cfg.steps,
            skipped=run["skipped"],
            reverted=run["reverted"],
            has_signal=bool(np.ptp(self._evidence.signal) > 0),
            update_index=self.n_updates,
            t0=t0,
            fit=run["last"].get("fit", math.nan),
            evidence_rows=len(self._evidence),
            kl=run["kl"],
            **info,
            **info_classifier,
            **info_level,
        )

    def _paper_update(self, xi_arr: NDArray[np.float64], ret: NDArray[np.float64]) -> dict[str, Any]:
        """The GoFlow paper's update: K Adam steps on the loss of the module docstring."""
        t0 = time.perf_counter()
        cfg = self.config
        weights_np, has_signal = standardize_returns(ret)
        weights = torch.as_tensor(weights_np, dtype=torch.float32)
        y_batch = torch.as_tensor(self._to_box(xi_arr), dtype=torch.float32).clamp(-BOX_BOUND, BOX_BOUND)
        gen = self._update_generator()
        y_old = self._draw_box(max(cfg.kl_pool, cfg.kl_samples), gen)  # draws of the frozen pre-update flow
        lq_old = self._log_q(y_old)
        step_loss = paper_loss(cfg, self._flow, gen, self.space.dim, y_batch, weights, y_old, lq_old)
        run = self._descend(step_loss, y_old, lq_old)
        return update_diagnostics(
            ret,
            self.entropy(),
            first=run["first"],
            last=run["last"],
            steps=cfg.steps,
            skipped=run["skipped"],
            reverted=run["reverted"],
            has_signal=has_signal,
            update_index=self.n_updates,
            t0=t0,
            reward_term=run["last"].get("reward_term", math.nan),
            entropy_objective=run["last"].get("entropy_objective", math.nan),
            kl=run["kl"],
        )  # KL(q_old || q_new) on the old flow's samples, after any revert

    # -- checkpoints -----------------------------------------------------------------------------

    def state_dict(self) -> dict[str, Any]:
        """JSON-serializable: type, space, config (alpha and beta included), update count and the
        flow's tensors."""
        return {
            "type": type(self).__name__,
            "space": self.space.to_dict(),
            "config": self.config.to_dict(),
            "n_updates": self.n_updates,
            "flow": {k: tensor_to_json(v) for k, v in self._flow.state_dict().items()},
            "evidence": self._evidence.state_dict(),
            **({"classifier": self._classifier.state_dict()} if self._classifier is not None else {}),
            "feasible_level": self._level,
        }

    def load_state_dict(self, state: Mapping[str, Any]) -> None:
        """Restore the flow and update count (the config, alpha, beta and seed are restored too;
        states that hold alpha and beta beside the config, as older checkpoints do, load as well).

        Raises ValueError for another sampler type, another ParamSpace, or another flow architecture.
        """
        check_state_dict(self.space, state, type(self).__name__)
        try:
            config = GoFlowConfig.from_dict(goflow_config_of(state))
            n_updates = int(state["n_updates"])
            tensors = {k: tensor_from_json(v) for k, v in state["flow"].items()}
        except (KeyError, TypeError, AttributeError) as exc:
            raise ValueError(f"load_state_dict: malformed GoFlowSampler state_dict ({exc!r})") from exc
        diffs = [
            f"{name}: {getattr(self.config, name)!r} vs {getattr(config, name)!r}"
            for name in GoFlowConfig.ARCHITECTURE
            if getattr(self.config, name) != getattr(config, name)
        ]
        if diffs:
            raise ValueError("load_state_dict: flow architecture differs (this vs checkpoint): " + "; ".join(diffs))
        if not all(torch.isfinite(t).all() for t in tensors.values() if t.is_floating_point()):
            raise ValueError("load_state_dict: the checkpoint's flow has non-finite parameters")
        try:
            self._flow.load_state_dict(tensors)
        except RuntimeError as exc:
            raise ValueError(f"load_state_dict: flow tensors do not fit this architecture: {exc}") from exc
        evidence = SignalMemory(
            self.space.dim, config.memory, config.neighbours, config.signal_range, config.boundary_memory
        )
        evidence.load_state_dict(state.get("evidence", {}))
        classifier = self._make_classifier(config)
        if classifier is not None and "classifier" in state:
            classifier.load_state_dict(state["classifier"])
        level = check_number(
            state.get("feasible_level", config.feasible_level), "state feasible_level", 0.0, 1.0, low_open=True
        )
        self.config, self.n_updates, self._evidence, self._classifier = config, n_updates, evidence, classifier
        self._level = level
        self._entropy_cache = None
        self._refresh_gate()

    @classmethod
    def from_state_dict(cls, state: Mapping[str, Any]) -> GoFlowSampler:
        """Build a sampler from a `state_dict` alone."""
        space = ParamSpace.from_dict(state["space"])
        sampler = cls(space, None, goflow_config_of(state))
        sampler.load_state_dict(state)
        return sampler

    def __getstate__(self) -> dict[str, Any]:
        """Pickle through the JSON state (compact and independent of zuko's module internals)."""
        return self.state_dict()

    def __setstate__(self, state: dict[str, Any]) -> None:
        other = type(self).from_state_dict(state)
        self.__dict__.update(other.__dict__)

    def __repr__(self) -> str:
        return f"GoFlowSampler(alpha={self.alpha}, beta={self.beta}, updates={self.n_updates}, space={self.space})"
