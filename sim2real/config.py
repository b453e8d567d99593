"""The diagnosis's settings: one frozen dataclass for every stage (clean, replay, band, fit, verdict)."""

from __future__ import annotations

import dataclasses

from goflow_common.checks import check_int, check_number
from goflow_common.errors import InputError
from sim2real.band import BandConfig
from sim2real.catalogue import CATALOGUE
from sim2real.clean import CleanConfig
from sim2real.replay import ReplayConfig

__all__ = ["DiagnosisConfig"]


@dataclasses.dataclass(frozen=True)
class DiagnosisConfig:
    """blocks: contiguous time blocks (folds are groups of them); folds: cross-validation folds;
    bootstrap: resamples for intervals; effects: the catalogue effects to consider (None: all
    that the log's channels can show); max_effects: most effects forward selection may add;
    min_gain: least held-out gain, as a fraction of the nominal excess over the noise floor, for
    an effect to be added, and min_gain_abs the least in noise variances (2 % of the noise
    variance: below it an effect is too weak to tell from the model's own small misfits, which
    reach 0.3 % on the simulated reality's nominal logs); explained: fraction of the excess the selection must close for the
    verdict "explained"; structure: the least share of the excess that structure left in the
    residual after the selection (a generic function of the joint velocity, a trend in time:
    sim2real/structure.py) must predict on held-out data for the verdict to read "unexplained"
    although the selection closes `explained` of it; structure_rest: the same, as a share of
    what the selection leaves above the level of a log with no gap (a large effect outside the
    catalogue that several catalogue effects mimic leaves a small share of its excess, but most
    of what is left is structure); floor_tolerance: the excess over the noise floor [noise
    variances] within the floor's own uncertainty (a floor read 10 % low in standard deviation
    reads a log with no gap 0.23 high): an excess whose interval's lower end is below it is not a
    gap by itself; seed: of the bootstrap; replay, clean, band: the stages' settings (band None:
    every sample, the fast-part/variogram floor of the version before the band)."""

    blocks: int = 20
    folds: int = 5
    bootstrap: int = 300
    effects: tuple[str, ...] | None = None
    max_effects: int = 4
    min_gain: float = 0.005
    min_gain_abs: float = 0.02
    explained: float = 0.6
    structure: float = 0.05
    structure_rest: float = 0.25
    floor_tolerance: float = 0.25
    seed: int = 0
    replay: ReplayConfig = dataclasses.field(default_factory=ReplayConfig)
    clean: CleanConfig = dataclasses.field(default_factory=CleanConfig)
    band: BandConfig | None = dataclasses.field(default_factory=BandConfig)

    def __post_init__(self) -> None:
        check_int(self.blocks, "DiagnosisConfig.blocks", 4)
        check_int(self.folds, "DiagnosisConfig.folds", 2)
        if self.blocks % self.folds:
            raise InputError(f"DiagnosisConfig.blocks = {self.blocks}; expected a multiple of folds = {self.folds}")
        check_int(self.bootstrap, "DiagnosisConfig.bootstrap", 20)
        check_int(self.max_effects, "DiagnosisConfig.max_effects", 1)
        check_number(self.min_gain, "DiagnosisConfig.min_gain", 0.0, 1.0)
        check_number(self.explained, "DiagnosisConfig.explained", 0.0, 1.0)
        check_number(self.structure, "DiagnosisConfig.structure", 0.0, 1.0)
        check_number(self.structure_rest, "DiagnosisConfig.structure_rest", 0.0, 1.0)
        check_number(self.floor_tolerance, "DiagnosisConfig.floor_tolerance", 0.0, 100.0)
        for name in self.effects or ():
            if name not in CATALOGUE:
                raise InputError(f"DiagnosisConfig.effects has {name!r}; expected names from {sorted(CATALOGUE)}")
