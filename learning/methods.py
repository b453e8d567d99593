"""Names of the domain-randomization methods (kept light: the CLI imports it to build its flags)."""

METHODS: tuple[str, ...] = ("nodr", "fulldr", "adr", "lsdr", "doraemon", "goflow")
