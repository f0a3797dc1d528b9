"""`payload-agent serve` over OPC UA: a real asyncua client against the served agent and a simulated EC66
(its real JSON-RPC protocol on loopback): security by default, the model, the PLCopen handshake."""

from __future__ import annotations

import asyncio
import math
import shutil
import socket
import time

import pytest
import yaml

pytest.importorskip("asyncua")
from asyncua import Client, ua  # noqa: E402
from asyncua.crypto.cert_gen import setup_self_signed_certificate  # noqa: E402
from cryptography.x509.oid import ExtendedKeyUsageOID  # noqa: E402

from conftest import ROOT, tweak  # noqa: E402
from payload_agent.configuration.config import parse_config  # noqa: E402
from payload_agent.plc.jobs import ERROR_BUSY, RobotJobs  # noqa: E402
from payload_agent.plc.opcua_server import NAMESPACE, OpcUaServer, ServerThread  # noqa: E402
from payload_agent.plc.serve_config import ServeConfig, UserSpec, hash_password  # noqa: E402
from payload_agent.recording.state import RobotState  # noqa: E402
from payload_agent.session.simulation import SimulatedCell  # noqa: E402
from payload_agent.tools import library  # noqa: E402
from payload_agent.tools.library import ToolEntry  # noqa: E402

WAIT_S = 60.0  # generous: jobs run real sessions, and the host may be loaded


def _free_port() -> int:
    s = socket.socket()
    s.bind(("127.0.0.1", 0))
    port = s.getsockname()[1]
    s.close()
    return port


@pytest.fixture(scope="module")
def served(tmp_path_factory):
    tmp = tmp_path_factory.mktemp("opcua")
    data = yaml.safe_load((ROOT / "configs" / "sim-ec66.yaml").read_text())
    data = tweak(data, "driver.rpc_port", 0)
    data = tweak(data, "driver.monitor_port", 0)
    data = tweak(data, "storage", {"runs_dir": str(tmp / "runs"), "state_dir": str(tmp / "state")})
    config = parse_config(data, source="test")
    db = library.tool_library_path(RobotState.for_config(config).root)
    # its inertia: principal moments 4, 6, 2 g·m² about axes turned 30° about the flange z axis
    c, s_ = math.cos(math.radians(30)), math.sin(math.radians(30))
    xx, yy, xy = 0.004 * c * c + 0.006 * s_ * s_, 0.004 * s_ * s_ + 0.006 * c * c, (0.004 - 0.006) * c * s_
    library.store(db, config.robot.name, ToolEntry("gripper", 2.0, (40.0, -25.0, 70.0), 0.002, (0.5, 0.5, 0.6),
                                                   inertia_com_kgm2=(xx, yy, 0.002, xy, 0.0, 0.0), number=3))
    users = (UserSpec("plc", hash_password("secret", iterations=1000), "operator"),
             UserSpec("scada", hash_password("look", iterations=1000), "reader"))
    url = f"opc.tcp://127.0.0.1:{_free_port()}/payload-agent/"
    cell = SimulatedCell(config).start()
    jobs = RobotJobs(config, cell=cell)
    server = ServerThread(OpcUaServer(ServeConfig(endpoint=url, users=users), [jobs], tmp / "certs")).start()
    key, cert = tmp / "client-key.pem", tmp / "client-cert.der"
    asyncio.run(setup_self_signed_certificate(key, cert, "urn:payload-agent:test-client", "localhost",
                                              [ExtendedKeyUsageOID.CLIENT_AUTH], {"commonName": "test client"}))
    shutil.copy(cert, tmp / "certs" / "trusted" / "plc.der")  # the administrator trusts this client
    stranger_key, stranger = tmp / "stranger-key.pem", tmp / "stranger-cert.der"
    asyncio.run(setup_self_signed_certificate(stranger_key, stranger, "urn:payload-agent:test-client", "localhost",
                                              [ExtendedKeyUsageOID.CLIENT_AUTH], {"commonName": "stranger"}))
    try:
        yield dict(url=url, cert=cert, key=key, jobs=jobs, cell=cell, config=config, certs=tmp / "certs",
                   stranger=(stranger, stranger_key))
    finally:
        server.stop()
        cell.close()


async def _client(s, user=None, password=None, cert=None) -> Client:
    # the client's health probe (asyncua 2.1: the server's state read every 1 s, answered within 1 s, else the
    # connection counts as lost) gave up once on a busy host; these tests are not about it
    c = Client(s["url"], timeout=20, watchdog_intervall=10.0)
    c.application_uri = "urn:payload-agent:test-client"
    if user is not None:
        c.set_user(user)
        c.set_password(password)
    cert, key = cert or (s["cert"], s["key"])
    await c.set_security_string(f"Basic256Sha256,SignAndEncrypt,{cert},{key}")
    return c


async def _controller(cell, method: str, *args):
    """A call on the simulated controller (its own process: a pipe round trip) off the event loop the client
    runs on, so the client keeps answering meanwhile."""
    return await asyncio.to_thread(lambda: getattr(cell.controller, method)(*args))


async def _robot(c: Client):
    idx = await c.get_namespace_index(NAMESPACE)
    return idx, await c.nodes.objects.get_child([f"{idx}:PayloadAgent", f"{idx}:sim-ec66"])


async def _load(c: Client, robot):
    """FlangeLoad's parts by their standard browse names (Robotics LoadType, spatial types in namespace 0)."""
    idx = await c.get_namespace_index(NAMESPACE)
    rob = await c.get_namespace_index("http://opcfoundation.org/UA/Robotics/")
    load = await robot.get_child(f"{idx}:FlangeLoad")
    com = await load.get_child(f"{rob}:CenterOfMass")
    return rob, load, {"Mass": await load.get_child(f"{rob}:Mass"), "CenterOfMass": com,
                       "Inertia": await load.get_child(f"{rob}:Inertia"),
                       **{k: await com.get_child(["0:CartesianCoordinates", f"0:{k}"]) for k in "XYZ"},
                       **{k: await com.get_child(["0:Orientation", f"0:{k}"]) for k in "ABC"},
                       **{f"I{k}": await load.get_child([f"{rob}:Inertia", f"0:{k}"]) for k in "XYZ"}}


async def _wait(node, value, timeout_s=WAIT_S):
    deadline = time.monotonic() + timeout_s
    while time.monotonic() < deadline:
        if await node.read_value() == value:
            return
        await asyncio.sleep(0.05)
    raise AssertionError(f"{node} did not become {value!r} within {timeout_s} s")


def test_secure_by_default(served):
    assert (served["certs"] / "server-cert.der").exists() and (served["certs"] / "server-key.pem").exists()

    async def main():
        for user, pw in ((None, None), ("plc", "wrong"), ("nobody", "secret")):  # anonymous, wrong password
            with pytest.raises(Exception, match="BadUserAccessDenied|BadIdentityTokenRejected"):
                async with await _client(served, user, pw):
                    pass
        plain = Client(served["url"], timeout=20)  # no security: the server offers no such endpoint ...
        with pytest.raises(Exception, match="No matching endpoints"):
            async with plain:
                pass
        await _unencrypted_session_refused(served["url"])  # ... and activates no session on such a channel
        async with await _client(served, "scada", "look") as c:  # a reader browses and reads, never calls
            idx, robot = await _robot(c)
            _, _, load = await _load(c, robot)
            assert math.isnan(await load["Mass"].read_value())
            with pytest.raises(ua.UaStatusCodeError, match="BadUserAccessDenied"):
                await robot.call_method(f"{idx}:Apply", ua.Variant("gripper", ua.VariantType.String))
            execute = await robot.get_child([f"{idx}:Handshake", f"{idx}:Apply", f"{idx}:Execute"])
            with pytest.raises(ua.UaStatusCodeError, match="BadUserAccessDenied"):
                await execute.write_value(ua.Variant(True, ua.VariantType.Boolean))

    asyncio.run(main())
    assert not served["jobs"].busy and served["jobs"].last.command == ""  # nothing was started


async def _unencrypted_session_refused(url: str) -> None:
    c = Client(url, timeout=20)
    await c.connect_socket()
    try:
        await c.send_hello()
        await c.open_secure_channel()  # SecurityPolicy#None
        params = ua.CreateSessionParameters(ClientNonce=b"0" * 32, EndpointUrl=url, SessionName="plain",
                                            RequestedSessionTimeout=60000, MaxResponseMessageSize=0,
                                            ClientDescription=ua.ApplicationDescription(
                                                ApplicationUri="urn:x", ApplicationType=ua.ApplicationType.Client))
        await c.uaclient.create_session(params)
        token = ua.UserNameIdentityToken(UserName="plc", Password=b"secret", PolicyId="username_basic256sha256")
        with pytest.raises(ua.UaStatusCodeError, match="BadUserAccessDenied"):
            await c.uaclient.activate_session(ua.ActivateSessionParameters(UserIdentityToken=token, LocaleIds=["en"]))
        read = ua.ReadParameters(NodesToRead=[ua.ReadValueId(NodeId=ua.NodeId(ua.ObjectIds.Server_ServerStatus_State),
                                                             AttributeId=ua.AttributeIds.Value)])
        with pytest.raises(ua.UaStatusCodeError, match="BadSessionNotActivated"):
            await c.uaclient.read(read)
    finally:
        c.disconnect_socket()


def test_handshake_apply_busy_done_and_error_codes(served):
    cell, jobs = served["cell"], served["jobs"]

    async def main():
        async with await _client(served, "plc", "secret") as c:
            idx, robot = await _robot(c)
            tools = await robot.get_child(f"{idx}:Tools")
            assert [(await t.read_browse_name()).Name for t in await tools.get_children()] == ["gripper"]
            rob, flange_load, load = await _load(c, robot)
            mass = load["Mass"]
            units = await (await mass.get_child("0:EngineeringUnits")).read_value()
            assert units.DisplayName.Text == "kg"
            # the standard types: FlangeLoad is a Robotics LoadType, Mass an AnalogUnitType, CenterOfMass a
            # 3DFrameType and Inertia a 3DVectorType (OPC 10000-5); the groups are DI FunctionalGroupTypes
            assert await flange_load.read_type_definition() == ua.NodeId(1018, rob)
            assert await mass.read_type_definition() == ua.NodeId(ua.ObjectIds.AnalogUnitType)
            assert await load["CenterOfMass"].read_type_definition() == ua.NodeId(ua.ObjectIds.ThreeDFrameType)
            assert await load["Inertia"].read_type_definition() == ua.NodeId(ua.ObjectIds.ThreeDVectorType)
            di = await c.get_namespace_index("http://opcfoundation.org/UA/DI/")
            assert await (await robot.get_child(f"{idx}:Handshake")).read_type_definition() == ua.NodeId(1005, di)
            status = (await load["IX"].read_data_value(raise_on_bad_status=False)).StatusCode
            assert status.value == ua.StatusCodes.BadWaitingForInitialData  # no inertia known yet
            blk = {k: await robot.get_child([f"{idx}:Handshake", f"{idx}:Apply", f"{idx}:{k}"])
                   for k in ("Execute", "ToolName", "Busy", "Done", "Error", "ErrorID", "Message")}
            verify_err = await robot.get_child([f"{idx}:Handshake", f"{idx}:Verify", f"{idx}:ErrorID"])
            # a controller that answers far too late keeps the Apply job busy: a second start is refused
            await _controller(cell, "inject_fault", "slow_reply")
            await blk["ToolName"].write_value(ua.Variant("gripper", ua.VariantType.String))
            await blk["Execute"].write_value(ua.Variant(True, ua.VariantType.Boolean))
            await _wait(blk["Busy"], True)
            with pytest.raises(ua.UaStatusCodeError, match="BadInvalidState"):
                await robot.call_method(f"{idx}:Verify", ua.Variant("gripper", ua.VariantType.String))
            await _wait(verify_err, ERROR_BUSY)  # the refused start shows in its block
            await _controller(cell, "clear_faults")
            await _wait(blk["Busy"], False)
            await blk["Execute"].write_value(ua.Variant(False, ua.VariantType.Boolean))  # PLCopen: reset outputs
            await _wait(blk["Done"], False)
            assert await blk["Error"].read_value() is False and await blk["ErrorID"].read_value() == 0
            # the pendant took control back: the write cannot take; Error with the exit code, the cause named
            await _controller(cell, "inject_fault", "leave_remote")
            await blk["Execute"].write_value(ua.Variant(True, ua.VariantType.Boolean))
            await _wait(blk["Error"], True)
            assert await blk["ErrorID"].read_value() == 6
            assert "Likely cause" in await blk["Message"].read_value()
            await blk["Execute"].write_value(ua.Variant(False, ua.VariantType.Boolean))
            await _controller(cell, "clear_faults")
            await _controller(cell, "set_mode", 2)  # the operator turns the pendant's key back to remote
            await _wait(blk["Error"], False)
            # a healthy Apply: Done, the controller holds the library's payload, the model shows it
            await blk["Execute"].write_value(ua.Variant(True, ua.VariantType.Boolean))
            await _wait(blk["Done"], True)
            assert await blk["Error"].read_value() is False
            assert (await _controller(cell, "payload_setting"))["m"] == pytest.approx(2.0)
            await _wait(mass, 2.0)
            assert await load["X"].read_value() == pytest.approx(40.0)
            frame = await load["CenterOfMass"].read_value()  # the structured value says the same
            assert frame.CartesianCoordinates.Z == pytest.approx(70.0)
            # the library's inertia as principal moments with the orientation of their axes (LoadType)
            assert [await load[f"I{k}"].read_value() for k in "XYZ"] == pytest.approx([0.004, 0.006, 0.002])
            assert [await load[k].read_value() for k in "ABC"] == pytest.approx([30.0, 0.0, 0.0], abs=1e-6)
            assert frame.Orientation.A == pytest.approx(30.0) and (await load["Inertia"].read_value()).Y == \
                pytest.approx(0.006)
            last = {k: await (await robot.get_child([f"{idx}:LastResult", f"{idx}:{k}"])).read_value()
                    for k in ("Command", "Tool", "Verdict", "CenterOfMass")}
            assert last["Command"] == "Apply" and last["Tool"] == "gripper" and last["Verdict"] == "applied"
            assert last["CenterOfMass"] == pytest.approx([40.0, -25.0, 70.0])
            # a method call starts a job too; an unknown tool is a data error (exit code 5)
            code = await robot.call_method(f"{idx}:Apply", ua.Variant("no-such-tool", ua.VariantType.String))
            assert code == 0
            await _wait(blk["Error"], True)
            assert await blk["ErrorID"].read_value() == 5

    asyncio.run(main())


def test_only_trusted_client_certificates_open_a_session(served):
    """A client whose certificate is not in the trust folder is refused at CreateSession, whatever its password;
    its certificate is kept in rejected/ and, moved into trusted/ by the administrator, is accepted."""
    trusted, rejected = served["certs"] / "trusted", served["certs"] / "rejected"

    async def main():
        with pytest.raises(Exception, match="BadCertificateUntrusted"):
            async with await _client(served, "plc", "secret", cert=served["stranger"]):
                pass
        kept = list(rejected.glob("*.der"))
        assert len(kept) == 1
        async with await _client(served, "scada", "look"):  # the trusted client still gets in
            pass
        shutil.move(str(kept[0]), trusted / kept[0].name)  # the administrator admits it
        async with await _client(served, "scada", "look", cert=served["stranger"]) as c:
            idx, robot = await _robot(c)
            assert await (await robot.get_child(f"{idx}:State")).read_value()
        (trusted / kept[0].name).unlink()  # and revokes it: refused again, without a restart
        with pytest.raises(Exception, match="BadCertificateUntrusted"):
            async with await _client(served, "scada", "look", cert=served["stranger"]):
                pass

    asyncio.run(main())
    assert not served["jobs"].busy
