"""assembly package."""

import assembly.envs  # noqa: F401  (registers the goflow/... gymnasium ids)
