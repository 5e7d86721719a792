"""Whole systems on this machine: `abyss up` (the supervisor), its run directory and summary."""
