"""System identification: the log format, M, B, Af and LuGre from logs, the excitation trajectory, replay."""
