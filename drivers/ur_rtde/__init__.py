"""Universal Robots CB3 / e-Series driver through SDU's ur-rtde client library.

``URRTDEDriver`` (``driver``) fills the driver contract's hooks; ``URRTDEOptions`` (``options``)
is its YAML ``driver`` section; ``states`` maps UR's mode codes to what a user must do;
``dashboard`` is the small dashboard-server client (identification, the fallback stop).
"""

from payload_agent.errors import ConfigError

try:  # only this driver needs the wheel
    import rtde_control  # noqa: F401
    import rtde_receive  # noqa: F401
except ImportError as _exc:
    raise ConfigError(
        "driver.type",
        "the ur_rtde driver needs the ur-rtde package, which ships wheels for CPython 3.11 and 3.12 only; "
        "install it with `pip install 'payload-agent[ur]'` on one of those Python versions "
        f"(import failed: {_exc})",
    ) from _exc

from payload_agent.drivers.ur_rtde.driver import URRTDEDriver  # noqa: E402
from payload_agent.drivers.ur_rtde.options import URRTDEOptions  # noqa: E402

__all__ = ["URRTDEDriver", "URRTDEOptions"]
