"""The run folder: samples written as they arrive, read back for analysis; per-robot state folders."""
