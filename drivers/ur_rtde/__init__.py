"""Universal Robots CB3 / e-Series driver through SDU's ur-rtde client library.

``URRTDEDriver`` (``driver``) fills the driver contract's hooks; ``URRTDEOptions`` (``options``)
is its YAML ``driver`` section, importable without ur-rtde (the registry parses a robot YAML with it
alone); ``states`` maps UR's mode codes to what a user must do; ``dashboard`` is the small
dashboard-server client (identification, the fallback stop).
"""
