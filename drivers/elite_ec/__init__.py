"""Elite Robots EC series driver: JSON-RPC on 8055 (``rpc``), monitor frames on 8056 (``monitor``).

``EliteECDriver`` (``driver``) fills the driver contract's hooks; ``EliteECOptions``
(``options``) is its YAML ``driver`` section.
"""
