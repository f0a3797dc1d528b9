"""`payload-agent serve` over OPC UA (asyncua): per robot its flange load, tool library, last result and state,
and the Identify / Verify / Apply jobs with the PLCopen handshake (``plc.jobs``).

Address space, under Objects/PayloadAgent/<robot>/ (namespace ``NAMESPACE``; docs/production.md "The PLC in charge" lists every node),
built on the official OPC 10000-100 (DI) and OPC 40010-1 (Robotics) nodesets (``opcua_model``):

- ``FlangeLoad``: a Robotics ``LoadType`` instance: the payload this agent last wrote or verified,
  ``Mass`` (kg), ``CenterOfMass`` (3DFrame: X, Y, Z in mm from the flange; A, B, C of the principal axes
  of inertia), ``Inertia`` (3DVector: the principal moments, kg·m², BadWaitingForInitialData until an
  inertia is known), and the agent's ``ToolName``;
- ``Tools`` (DI FunctionalGroupType): one object per library tool (Mass, CenterOfMass [x, y, z] mm, their σ,
  Number, and the inertia's principal moments and axes where the library has them);
- ``LastResult``: Command, Tool, Verdict, Mass, CenterOfMass, MassStd, CenterOfMassStd, RunDir, Time, Message;
- ``State``: idle / busy: <command> / the last failure;
- ``Handshake/Identify``, ``Handshake/Verify``, ``Handshake/Apply``: the PLCopen blocks (Execute and ToolName
  writable; Busy, Done, Error, ErrorID, Message) and, on the robot object, methods ``Identify``, ``Verify``,
  ``Apply`` taking the tool name and returning the ErrorID of the start (0: started; a start while a job
  runs fails with BadInvalidState); a job a method started shows its progress in the same block.

Security: the only endpoint is Basic256Sha256 SignAndEncrypt; the server certificate and key are created on
first start in ``cert_dir``. Only client applications whose certificate is in the trust folder
(``opcua_trust``; default ``cert_dir/trusted``) may open a session; sessions then authenticate with a
user name and password (``serve_config``): operators may write and call, readers only browse and read;
anonymous sessions are refused unless ``anonymous_read``, and then only read.
"""

from __future__ import annotations

import asyncio
import math
import socket
import threading
from dataclasses import dataclass
from pathlib import Path
from typing import Callable

from asyncua import Server, ua
from asyncua.crypto.permission_rules import USER_TYPES, PermissionRuleset, User, UserRole
from asyncua.server.user_managers import UserManager

from payload_agent.plc.jobs import COMMANDS, RobotJobs
from payload_agent.plc.opcua_model import Namespaces, add_flange_load, add_group, load_standard_types, unit, write_load
from payload_agent.plc.opcua_trust import ClientTrustList
from payload_agent.plc.serve_config import ServeConfig
from payload_agent.recording.state import RobotState
from payload_agent.tools import library

NAMESPACE = "urn:payload-agent:plc"
APP_URI = "urn:payload-agent:server"
POLL_S = 0.05
_NO_WRITE = {ua.NodeId(ua.ObjectIds.WriteRequest_Encoding_DefaultBinary),
             ua.NodeId(ua.ObjectIds.CallRequest_Encoding_DefaultBinary)}


class _Users(UserManager):
    def __init__(self, serve: ServeConfig):
        self.serve = serve

    def get_user(self, iserver, username=None, password=None, certificate=None):
        if not certificate:
            # no client certificate: the secure channel is unencrypted (asyncua accepts a SecurityPolicy#None
            # channel even when no such endpoint is offered); no session of any kind is activated on it
            return None
        if username is None:
            return User(role=UserRole.Anonymous) if self.serve.anonymous_read else None
        spec = self.serve.user(username, password)
        if spec is None:
            return None  # a wrong password: the session is refused
        return User(role=UserRole.User if spec.role == "operator" else UserRole.Anonymous, name=spec.name)


class _Rules(PermissionRuleset):
    """Operators: every session service; readers and anonymous: the same without Write and Call."""

    def __init__(self):
        self.all = set(map(ua.NodeId, USER_TYPES))

    def check_validity(self, user, action_type_id, body):
        if user is not None and user.role in (UserRole.User, UserRole.Admin):
            return action_type_id in self.all
        return action_type_id in self.all and action_type_id not in _NO_WRITE


@dataclass
class _Block:
    execute: object
    tool: object
    outputs: dict[str, object]
    last_execute: bool = False


class OpcUaServer:
    """The served model of one or more robots; ``start``/``stop`` inside a running asyncio loop."""

    def __init__(self, serve: ServeConfig, robots: list[RobotJobs], cert_dir: Path,
                 log: Callable[[str], None] = lambda text: None):
        self.serve, self.robots, self.cert_dir, self.log = serve, robots, Path(cert_dir), log
        self.server = Server(user_manager=_Users(serve))
        self.trust = ClientTrustList(serve.trusted_clients_dir or self.cert_dir / "trusted", self.cert_dir / "rejected",
                                     log)
        self._ns: Namespaces | None = None
        self._loads: dict[str, object] = {}
        self._blocks: dict[tuple[str, str], _Block] = {}
        self._nodes: dict[str, dict[str, object]] = {}
        self._task: asyncio.Task | None = None

    async def _certificates(self) -> tuple[Path, Path]:
        from asyncua.crypto.cert_gen import setup_self_signed_certificate
        from cryptography.x509.oid import ExtendedKeyUsageOID

        self.cert_dir.mkdir(parents=True, exist_ok=True)
        key, cert = self.cert_dir / "server-key.pem", self.cert_dir / "server-cert.der"
        fresh = not key.exists()
        await setup_self_signed_certificate(key, cert, APP_URI, socket.gethostname(),
                                            [ExtendedKeyUsageOID.SERVER_AUTH, ExtendedKeyUsageOID.CLIENT_AUTH],
                                            {"commonName": "payload-agent", "organizationName": "payload-agent"})
        if fresh:
            self.log(f"OPC UA: created the server certificate {cert} (key {key})")
        key.chmod(0o600)
        return key, cert

    async def start(self) -> None:
        key, cert = await self._certificates()
        await self.server.init()
        self.server.set_endpoint(self.serve.endpoint)
        self.server.set_server_name("payload-agent")
        await self.server.set_application_uri(APP_URI)
        self.server.set_security_policy([ua.SecurityPolicyType.Basic256Sha256_SignAndEncrypt],
                                        permission_ruleset=_Rules())
        tokens = [ua.UserNameIdentityToken] + ([ua.AnonymousIdentityToken] if self.serve.anonymous_read else [])
        self.server.set_identity_tokens(tokens)
        await self.server.load_certificate(str(cert))
        await self.server.load_private_key(str(key))
        self.trust.ensure_folders()
        self.server.set_certificate_validator(self.trust)
        self._ns = await load_standard_types(self.server, NAMESPACE)
        idx = self._ns.own
        root = await self.server.nodes.objects.add_object(idx, "PayloadAgent")
        for jobs in self.robots:
            await self._robot_nodes(idx, root, jobs)
        await self.server.start()
        self._task = asyncio.create_task(self._poll())
        n_trusted = len(self.trust.trusted())
        self.log(f"OPC UA: serving {', '.join(j.config.robot.name for j in self.robots)} at {self.serve.endpoint} "
                 "(Basic256Sha256 SignAndEncrypt; " + ("anonymous read allowed" if self.serve.anonymous_read
                                                      else "no anonymous sessions")
                 + f"; {n_trusted} trusted client certificate(s) in {self.trust.trusted_dir})")
        if not n_trusted:
            self.log(f"OPC UA: no client can open a session until its certificate is in {self.trust.trusted_dir} "
                     f"(a refused client's certificate is kept in {self.trust.rejected_dir} to move over)")

    async def stop(self) -> None:
        if self._task is not None:
            self._task.cancel()
            try:
                await self._task
            except asyncio.CancelledError:
                pass
        await self.server.stop()

    # -- address space ---------------------------------------------------------------------
    async def _var(self, parent, idx, name, value, vtype, unit_code: str | None = None, writable: bool = False):
        node = await parent.add_variable(idx, name, ua.Variant(value, vtype))
        if unit_code is not None:
            await node.add_property(0, "EngineeringUnits", unit(unit_code))
        if writable:
            await node.set_writable()
        return node

    async def _robot_nodes(self, idx, root, jobs: RobotJobs) -> None:
        name = jobs.config.robot.name
        obj = await root.add_object(idx, name)
        n: dict[str, object] = {}
        D, S = ua.VariantType.Double, ua.VariantType.String
        n["State"] = await self._var(obj, idx, "State", jobs.state, S)
        assert self._ns is not None
        self._loads[name] = await add_flange_load(obj, self._ns)
        load = await obj.get_child(f"{idx}:FlangeLoad")
        n["LoadTool"] = await self._var(load, idx, "ToolName", "", S)
        n["Tools"] = await add_group(obj, self._ns, "Tools")
        last = await add_group(obj, self._ns, "LastResult")
        for key, vt, u in (("Command", S, None), ("Tool", S, None), ("Verdict", S, None), ("Mass", D, "kg"),
                              ("MassStd", D, "kg"), ("RunDir", S, None), ("Time", S, None), ("Message", S, None)):
            n[f"Last{key}"] = await self._var(last, idx, key, "" if vt == S else math.nan, vt, u)
        for key in ("CenterOfMass", "CenterOfMassStd"):
            n[f"Last{key}"] = await self._var(last, idx, key, [math.nan] * 3, D, "mm")
        handshakes = await add_group(obj, self._ns, "Handshake")
        for command in COMMANDS:
            blk = await add_group(handshakes, self._ns, command)
            outputs = {k: await self._var(blk, idx, k, v, t) for k, v, t in (
                ("Busy", False, ua.VariantType.Boolean), ("Done", False, ua.VariantType.Boolean),
                ("Error", False, ua.VariantType.Boolean), ("ErrorID", 0, ua.VariantType.Int32),
                ("Message", "", S))}
            self._blocks[(name, command)] = _Block(
                await self._var(blk, idx, "Execute", False, ua.VariantType.Boolean, writable=True),
                await self._var(blk, idx, "ToolName", "", S, writable=True), outputs)
            await obj.add_method(idx, command, self._method(jobs, command), [ua.VariantType.String],
                                 [ua.VariantType.Int32])
        self._nodes[name] = n
        await self._refresh(jobs)
        await self._refresh_tools(idx, jobs)

    def _method(self, jobs: RobotJobs, command: str):
        async def call(parent, tool):
            started, code, message = jobs.start(command, str(tool.Value or ""))
            if not started:
                return ua.StatusCode(ua.StatusCodes.BadInvalidState)  # refused: the running job is left alone
            return [ua.Variant(code, ua.VariantType.Int32)]
        return call

    async def _refresh_tools(self, idx, jobs: RobotJobs) -> None:
        folder = self._nodes[jobs.config.robot.name]["Tools"]
        for child in await folder.get_children():
            await self.server.delete_nodes([child], recursive=True)
        db = library.tool_library_path(RobotState.for_config(jobs.config).root)
        for t in library.list_tools(db, jobs.config.robot.name):
            obj = await folder.add_object(idx, t.name)
            D = ua.VariantType.Double
            await self._var(obj, idx, "Mass", t.mass_kg, D, "kg")
            await self._var(obj, idx, "CenterOfMass", list(t.cog_mm), D, "mm")
            await self._var(obj, idx, "MassStd", math.nan if t.mass_std_kg is None else t.mass_std_kg, D, "kg")
            await self._var(obj, idx, "CenterOfMassStd", list(t.cog_std_mm or (math.nan,) * 3), D, "mm")
            await self._var(obj, idx, "Number", t.number or 0, ua.VariantType.Int32)
            principal = t.principal_inertia()
            if principal is not None:
                await self._var(obj, idx, "PrincipalMoments", list(principal[0]), D, "kgm2")
                await self._var(obj, idx, "PrincipalAxesABC", list(principal[1]), D, "deg")

    async def _refresh(self, jobs: RobotJobs) -> None:
        n = self._nodes[jobs.config.robot.name]
        D, S = ua.VariantType.Double, ua.VariantType.String
        await n["State"].write_value(ua.Variant(jobs.state, S))
        load = jobs.load
        await write_load(self._loads[jobs.config.robot.name], load.mass_kg, load.cog_mm,  # type: ignore[arg-type]
                         load.orientation_deg, load.inertia_kgm2)
        await n["LoadTool"].write_value(ua.Variant(jobs.load.tool, S))
        last = jobs.last
        for key, value in (("Command", last.command), ("Tool", last.tool), ("Verdict", last.verdict),
                           ("RunDir", last.run_dir), ("Time", last.time_utc), ("Message", last.message[:2000])):
            await n[f"Last{key}"].write_value(ua.Variant(value, S))
        await n["LastMass"].write_value(ua.Variant(float(last.mass_kg), D))
        await n["LastMassStd"].write_value(ua.Variant(float(last.mass_std_kg), D))
        await n["LastCenterOfMass"].write_value(ua.Variant([float(c) for c in last.cog_mm], D))
        await n["LastCenterOfMassStd"].write_value(ua.Variant([float(c) for c in last.cog_std_mm], D))
        for command in COMMANDS:
            hs, blk = jobs.handshakes[command], self._blocks[(jobs.config.robot.name, command)]
            for key, value, vt in (("Busy", hs.busy, ua.VariantType.Boolean), ("Done", hs.done, ua.VariantType.Boolean),
                                   ("Error", hs.error, ua.VariantType.Boolean),
                                   ("ErrorID", int(hs.error_id), ua.VariantType.Int32),
                                   ("Message", hs.message[:2000], S)):
                await blk.outputs[key].write_value(ua.Variant(value, vt))

    async def _poll(self) -> None:
        idx = await self.server.get_namespace_index(NAMESPACE)
        was_busy = {j.config.robot.name: False for j in self.robots}
        while True:
            for jobs in self.robots:
                name = jobs.config.robot.name
                for command in COMMANDS:
                    blk = self._blocks[(name, command)]
                    execute = bool(await blk.execute.read_value())
                    if execute and not blk.last_execute:
                        jobs.start(command, str(await blk.tool.read_value() or ""))
                    elif not execute and blk.last_execute:
                        jobs.reset(command)
                    blk.last_execute = execute
                if jobs.changed.is_set():
                    jobs.changed.clear()
                    await self._refresh(jobs)
                    if was_busy[name] and not jobs.busy:
                        await self._refresh_tools(idx, jobs)
                    was_busy[name] = jobs.busy
            await asyncio.sleep(POLL_S)


class ServerThread:
    """An OpcUaServer on its own asyncio loop in a thread (for `serve` next to other servers, and tests)."""

    def __init__(self, server: OpcUaServer):
        self.server = server
        self.loop = asyncio.new_event_loop()
        self._thread = threading.Thread(target=self.loop.run_forever, daemon=True, name="opcua-server")

    def start(self, timeout_s: float = 60.0) -> "ServerThread":
        self._thread.start()
        asyncio.run_coroutine_threadsafe(self.server.start(), self.loop).result(timeout_s)
        return self

    def stop(self, timeout_s: float = 10.0) -> None:
        try:
            asyncio.run_coroutine_threadsafe(self.server.stop(), self.loop).result(timeout_s)
        finally:
            self.loop.call_soon_threadsafe(self.loop.stop)
            self._thread.join(timeout_s)
