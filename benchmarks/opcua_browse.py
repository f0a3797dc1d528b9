"""Browse a served payload-agent OPC UA model and print it as a tree (the capture in docs/plc.md).

    python -m benchmarks.opcua_browse opc.tcp://127.0.0.1:4840/payload-agent/ USER PASSWORD [--call-apply TOOL]
        [--client-dir DIR]

Connects like a PLC or SCADA client would: Basic256Sha256 SignAndEncrypt with a client certificate (created
once in ``--client-dir``, default ./opcua-browse-client; the server admits it only once its ``cert.der`` is
in the server's trust folder, see docs/security.md), a user name and password. Prints every node under
Objects/PayloadAgent with its value, and the standard type of each typed object or structured variable.
"""

from __future__ import annotations

import argparse
import asyncio
import sys
from pathlib import Path


async def _tree(node, depth: int, out: list[str]) -> None:
    from asyncua import ua

    for child in await node.get_children(refs=ua.ObjectIds.HierarchicalReferences):
        name = (await child.read_browse_name()).Name
        cls = await child.read_node_class()
        line = "  " * depth + name
        typedef = await child.read_type_definition() if cls in (ua.NodeClass.Object, ua.NodeClass.Variable) else None
        typename = None
        if typedef is not None and typedef.Identifier not in (ua.ObjectIds.BaseObjectType, ua.ObjectIds.FolderType,
                                                               ua.ObjectIds.BaseDataVariableType, ua.ObjectIds.PropertyType):
            typename = (await child.new_node(child.session, typedef).read_browse_name()).Name
        if cls == ua.NodeClass.Variable:
            try:
                value = await child.read_value()
                if isinstance(value, ua.EUInformation):
                    value = f"EUInformation({value.DisplayName.Text})"
                line += f" = {value!r}"
            except Exception as exc:  # a value with a bad status (Inertia before it is known)
                line += f" ({type(exc).__name__})"
        elif cls == ua.NodeClass.Method:
            line += "()  [method]"
        if typename is not None:
            line += f"  [{typename}]"
        out.append(line)
        if cls in (ua.NodeClass.Object, ua.NodeClass.Variable):
            await _tree(child, depth + 1, out)


async def main_async(url: str, user: str, password: str, call_apply: str | None, client_dir: Path) -> int:
    from asyncua import Client, ua
    from asyncua.crypto.cert_gen import setup_self_signed_certificate
    from cryptography.x509.oid import ExtendedKeyUsageOID

    from payload_agent.plc.opcua_server import NAMESPACE

    client_dir.mkdir(parents=True, exist_ok=True)
    key, cert = client_dir / "key.pem", client_dir / "cert.der"
    await setup_self_signed_certificate(key, cert, "urn:payload-agent:browse", "localhost",
                                        [ExtendedKeyUsageOID.CLIENT_AUTH], {"commonName": "browse"})
    client = Client(url, timeout=20)
    client.application_uri = "urn:payload-agent:browse"
    client.set_user(user)
    client.set_password(password)
    await client.set_security_string(f"Basic256Sha256,SignAndEncrypt,{cert},{key}")
    try:
        await client.connect()
    except ua.UaStatusCodeError as exc:
        if exc.code != ua.StatusCodes.BadCertificateUntrusted:
            raise
        print(f"the server does not trust this client yet: copy {cert} into its trust folder "
              "(<state>/<robot>/opcua/trusted/, or serve.yaml opcua.trusted_clients) and run again", file=sys.stderr)
        return 2
    try:
        idx = await client.get_namespace_index(NAMESPACE)
        root = await client.nodes.objects.get_child(f"{idx}:PayloadAgent")
        if call_apply:
            robot = (await root.get_children())[0]
            print(f"call Apply({call_apply!r}) -> ErrorID",
                  await robot.call_method(f"{idx}:Apply", ua.Variant(call_apply, ua.VariantType.String)))
            await asyncio.sleep(3.0)
        out = [f"{url}  (Basic256Sha256 SignAndEncrypt, user {user})", "Objects/PayloadAgent"]
        await _tree(root, 1, out)
        print("\n".join(out))
    finally:
        await client.disconnect()
    return 0


def main(argv: list[str] | None = None) -> int:
    p = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    p.add_argument("url")
    p.add_argument("user")
    p.add_argument("password")
    p.add_argument("--call-apply", metavar="TOOL")
    p.add_argument("--client-dir", type=Path, default=Path("opcua-browse-client"),
                   help="where the client's certificate and key are kept (created on first use)")
    a = p.parse_args(argv)
    return asyncio.run(main_async(a.url, a.user, a.password, a.call_apply, a.client_dir))


if __name__ == "__main__":
    sys.exit(main())
