"""The operator's tools: one command (`abyss op`), teleoperation, replaying a recording."""
