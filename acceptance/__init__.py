"""Acceptance measures that share no code with `acra` or `pipeline` (see `acceptance.visible`)."""
