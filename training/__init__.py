"""Training of the needle likelihood networks (needs the ``train`` extra: torch, lightning)."""
