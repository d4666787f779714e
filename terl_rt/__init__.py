"""terl-rt: the TERL encirclement world, its policies and tools, without torch."""
