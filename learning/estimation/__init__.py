"""Offline estimation of simulator parameter distributions from logged (s, a, s') data:
the dataset format, collection, NFPDE, DROPO and BayesSim, and the OT metric (docs/nfpde.md).

Kept light: the CLI imports it to build its flags."""

ESTIMATORS: tuple[str, ...] = ("nfpde-softmax", "nfpde-cai", "dropo", "bayessim")
