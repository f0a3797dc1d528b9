"""The plan (every PTP move, as data) and the safety gate, the only code that commands motion."""
