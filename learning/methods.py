"""Names of the domain-randomization methods (kept light: the CLI imports it to build its flags)."""

METHODS: tuple[str, ...] = ("nodr", "fulldr", "adr", "lsdr", "doraemon", "goflow")

#: Methods that compare returns with J_T themselves: they learn from returns, never 0/1 successes.
THRESHOLD_METHODS: tuple[str, ...] = ("adr", "doraemon")
#: Methods whose sampler is updated by gradient steps on a batch of (xi, signal).
GRADIENT_METHODS: tuple[str, ...] = ("lsdr", "goflow")
#: What a sampler may learn from: the episodes' returns, or their 0/1 successes (return >= J_T).
SAMPLER_SIGNALS: tuple[str, ...] = ("return", "success")
