"""An OPC UA client nobody here wrote (Python's asyncua) against `pkm-plc run --opcua`.

    opcua_client.py survey URL MACHINE
        Browses PkmPlc/MACHINE and reads every variable: JSON on stdout with, per process-image
        variable, its class folder, data type, type definition, IecType property, unit, EURange,
        value and source timestamp (s since the Unix epoch); the state, as text and as MainState
        (value, data type, type definition, EnumStrings); the Status values' data types; the
        classes' figures; the methods and whether this (anonymous) session may execute them; the
        server's StartTime and CurrentTime (read alone and in ServerStatus) and this computer's
        time when they were read.
    opcua_client.py subscribe URL MACHINE SECONDS [all] [events]
        Subscribes (publishing interval 50 ms, queue 4) to the main class's Cycles, the State and
        every JOINTn_POSITION (with `all`: every process-image variable; with `events`: the
        machine's condition events too) for SECONDS; JSON with the count of data changes per
        node, the latency of the Cycles updates (client receive time - source timestamp, same
        computer) and, with `events`, the count of events received.
    opcua_client.py endpoints URL
        The server's endpoints: JSON list of [security policy, mode, [user token types], URL]
        (the URL the server advertises for each).
    opcua_client.py alarms URL MACHINE [--user NAME --password PW] STEP ...
        Subscribes to the events of MACHINE's alarms and conditions (AlarmConditionType and its
        subtypes) and carries out the steps in turn: refresh (ConditionRefresh), a method of the
        machine (Stop, ...), wait=NAME:active|inactive|acked, ack=NAME (Acknowledge the
        condition's latest event), sleep=SECONDS. JSON: every event received (name, active,
        acked, retain, message, severity, type, user) and each step's outcome.
    opcua_client.py history URL MACHINE NAME SECONDS PART
        Reads the raw history of NAME (MainState, BusFault or a process-image variable) over the
        last SECONDS, whole and PART values a read: JSON with the values ([time, value]), the
        reads the parts took and the values they gave.
    opcua_client.py machinery URL MACHINE
        What an MES sees of OPC 40001-1 Machinery: the namespace array; the browse names in the
        Machines folder; MACHINE found there by browse path (TranslateBrowsePathsToNodeIds with
        the DI and Machinery namespaces' names); its Identification's type and fields; its
        MachineryBuildingBlocks' add-ins; MachineryItemState's and MachineryOperationMode's type,
        CurrentState, Id (the state's browse name) and Number; "together": the PLC's State and
        both CurrentStates read in one Read; a tree of it all, to print.
    opcua_client.py typecheck URL NODEID
        Checks the instance at NODEID against the type definitions the server itself serves, as
        a tool that works from types does: every Mandatory instance declaration of its type and
        of the type's supertypes (and of each declaration, down the hierarchy) present below
        it with the same browse name (namespace and name), node class, type definition (or a
        subtype) and data type (or a subtype); every child whose type is a companion's (a
        placeholder's instance: a channel, a tool, a job) checked against its own type; every
        object below NODEID, and the objects of namespace urn:pkm-plc, with a type definition.
        JSON: the nodes and declarations checked, and what is missing, wrong or untyped.
    opcua_client.py machine_tool URL MACHINE
        The OPC 40501-1 view of MACHINE as umati reads it, by browse paths: its type, the
        operation mode, the channel's state, mode and overrides, the spindle, the active
        program's name and state, the job's state and runs, the prognoses (a time as seconds
        since 1970) and the tools, and when it was read ("read_at"). JSON.
    opcua_client.py messages URL MACHINE SECONDS
        Subscribes to the alarm events (AlarmConditionType) of MACHINE's Notification/Messages,
        prints "subscribed", then each event as it comes for SECONDS: a JSON line with its
        condition name and whether it is active.
    opcua_client.py usercert DIR
        Makes a user certificate and key in DIR (cert.der, key.pem) for an X.509 identity token.
    opcua_client.py abandon URL N
        Opens N anonymous sessions, each on a connection of its own, and drops the connections
        without closing the sessions (as a client that crashed, or an attacker, leaves them):
        JSON with how many sessions were opened and the status of those refused.
    opcua_client.py hold URL N SECONDS FROM
        Opens N anonymous sessions, each on a connection of its own from the local address FROM
        (127.0.0.2, say), prints "held K" once they are open, and keeps them for SECONDS, reading
        the server's time every second on each (as a dashboard does): JSON with how many were
        opened and how many the server closed meanwhile, with the status it said.
    opcua_client.py channel URL SECONDS
        Opens a secure channel (None) and no session, then asks for the endpoints every half
        second on it for at most SECONDS: JSON with how long the connection lasted (s) and
        whether the server closed it.
    opcua_client.py guess URL USER COUNT PARALLEL
        Tries COUNT wrong passwords for USER, PARALLEL at a time, each on a connection of its
        own: JSON with how many were refused and how long they took in all (s).
    opcua_client.py call URL MACHINE [options] METHOD [METHOD ...]
        Calls the methods in turn (Load takes `Load=N`); between calls waits for the state a
        call should bring (`wait=STATE`). Options: --user NAME --password PW (--clear yes: the
        password sent in clear whatever the server asks), --user-cert DIR (log
        in with the certificate and key of `usercert DIR`), --secure DIR
        (Basic256Sha256 SignAndEncrypt with a client certificate made in DIR) and --pki DIR (the
        server's certificate store: a first connection is refused as untrusted, the server puts
        the certificate into rejected/, and this moves it to trusted/ as an administrator would,
        then connects again). JSON: per step, its status and result; "untrusted_first": whether
        the first connection was refused; "connect_seconds": how long the login took.
"""

import asyncio
import dataclasses
import datetime
import json
import shutil
import sys
import time
from pathlib import Path

from asyncua import Client, ua
from asyncua.crypto.security_policies import SecurityPolicyBasic256Sha256

NS = "urn:pkm-plc"


def unix(when):
    """Seconds since the Unix epoch of an OPC UA DateTime as asyncua gives it (UTC)."""
    if when is None:
        return None
    if when.tzinfo is None:
        when = when.replace(tzinfo=datetime.timezone.utc)
    return when.timestamp()


async def machine_node(client, machine):
    ns = await client.get_namespace_index(NS)
    root = await client.nodes.objects.get_child([f"{ns}:PkmPlc", f"{ns}:{machine}"])
    return ns, root


async def child(node, ns, name):
    return await node.get_child([f"{ns}:{name}"])


async def survey(url, machine):
    async with Client(url, timeout=10) as client:
        ns, root = await machine_node(client, machine)
        out = {"vars": {}, "classes": {}, "methods": {}, "program": []}
        out["state"] = await (await child(root, ns, "State")).read_value()
        classes = await child(root, ns, "TaskClasses")
        for cls in await classes.get_children():
            name = (await cls.read_browse_name()).Name
            figures = {}
            for fig in await cls.get_children():
                fname = (await fig.read_browse_name()).Name
                if fname == "Variables":
                    continue
                figures[fname] = await fig.read_value()
            out["classes"][name] = figures
            for var in await (await child(cls, ns, "Variables")).get_children():
                vname = (await var.read_browse_name()).Name
                dv = await var.read_data_value()
                dtype = await var.read_data_type()
                typedef = await var.read_type_definition()
                entry = {
                    "class": name,
                    "type": ua.object_ids.ObjectIdNames.get(dtype.Identifier, str(dtype)),
                    "typedef": ua.object_ids.ObjectIdNames.get(typedef.Identifier, str(typedef)),
                    "variant": dv.Value.VariantType.name,
                    "value": dv.Value.Value,
                    "source_ts": unix(dv.SourceTimestamp),
                }
                for prop in await var.get_properties():
                    pname = (await prop.read_browse_name()).Name
                    value = await prop.read_value()
                    if pname == "IecType":
                        entry["iec"] = value
                    elif pname == "EngineeringUnits":
                        entry["unit"] = value.DisplayName.Text
                        entry["unit_id"] = value.UnitId
                    elif pname == "EURange":
                        entry["range"] = [value.Low, value.High]
                out["vars"][vname] = entry
        for node in await root.get_children(refs=ua.ObjectIds.HasComponent, nodeclassmask=ua.NodeClass.Method):
            name = (await node.read_browse_name()).Name
            executable = await node.read_attribute(ua.AttributeIds.UserExecutable)
            out["methods"][name] = executable.Value.Value
        for node in await (await child(root, ns, "Program")).get_children():
            out["program"].append((await node.read_browse_name()).Name)
        main = await child(root, ns, "MainState")
        main_type = await main.read_data_type()
        enum_strings = await (await main.get_child(["0:EnumStrings"])).read_value()
        out["main_state"] = {
            "value": await main.read_value(),
            "type": ua.object_ids.ObjectIdNames.get(main_type.Identifier, str(main_type)),
            "typedef": ua.object_ids.ObjectIdNames.get(
                (await main.read_type_definition()).Identifier, ""
            ),
            "enum_strings": [t.Text for t in enum_strings],
        }
        out["status"] = {}
        for node in await (await child(root, ns, "Status")).get_children():
            dtype = await node.read_data_type()
            out["status"][(await node.read_browse_name()).Name] = ua.object_ids.ObjectIdNames.get(
                dtype.Identifier, str(dtype)
            )
        status = client.get_node(ua.ObjectIds.Server_ServerStatus)
        whole = await status.read_value()
        alone = await client.get_node(ua.ObjectIds.Server_ServerStatus_CurrentTime).read_value()
        out["server_time"] = {
            "start": unix(whole.StartTime),
            "current_in_status": unix(whole.CurrentTime),
            "current": unix(alone),
            "here": time.time(),
        }
        print(json.dumps(out))


class Counter:
    def __init__(self):
        self.counts = {}
        self.latencies_ms = []

    def datachange_notification(self, node, val, data):
        key = node.nodeid.to_string()
        self.counts[key] = self.counts.get(key, 0) + 1
        ts = data.monitored_item.Value.SourceTimestamp
        if key.endswith("Cycles") and ts is not None:
            self.latencies_ms.append((time.time() - ts.timestamp()) * 1000.0)


async def subscribe(url, machine, seconds, every=False, events=False):
    async with Client(url, timeout=10) as client:
        ns, root = await machine_node(client, machine)
        classes = await child(root, ns, "TaskClasses")
        main = None
        for cls in await classes.get_children():
            if (await cls.read_browse_name()).Name == "main":
                main = cls
        nodes = [await child(main, ns, "Cycles"), await child(root, ns, "State")]
        for cls in await classes.get_children():
            for var in await (await child(cls, ns, "Variables")).get_children():
                name = (await var.read_browse_name()).Name
                if every or (name.startswith("JOINT") and name.endswith("_POSITION")):
                    nodes.append(var)
        handler = Counter()
        sub = await client.create_subscription(50, handler)
        await sub.subscribe_data_change(nodes, sampling_interval=50, queuesize=4)
        if events:
            alarms = Alarms()
            events_sub = await client.create_subscription(50, alarms)
            await events_sub.subscribe_events(root, ua.ObjectIds.AlarmConditionType)
        await asyncio.sleep(seconds)
        await sub.delete()
        if events:
            await events_sub.delete()
        lat = sorted(handler.latencies_ms)
        out = {
            "counts": {k.split(";s=")[-1]: v for k, v in handler.counts.items()},
            "latency_ms": {
                "p50": lat[len(lat) // 2] if lat else None,
                "p99": lat[min(len(lat) - 1, int(len(lat) * 0.99))] if lat else None,
                "max": lat[-1] if lat else None,
            },
        }
        if events:
            out["events"] = len(alarms.events)
        print(json.dumps(out))


def options_and_steps(args, names):
    """The options `--NAME VALUE` of `args` whose NAMEs are `names` (a dict by NAME, None for one
    not given), and the other arguments in order: the steps."""
    options = dict.fromkeys(names)
    steps = []
    it = iter(args)
    for a in it:
        if a.startswith("--") and a[2:] in options:
            options[a[2:]] = next(it)
        else:
            steps.append(a)
    return options, steps


def path_or_none(text):
    return Path(text) if text is not None else None


async def call(url, machine, args):
    options, steps = options_and_steps(args, ["user", "password", "user-cert", "secure", "pki", "clear"])
    user, password = options["user"], options["password"]
    # --clear yes: the password is sent in clear, whatever the server's token policy asks (as a
    # client that ignores it would).
    clear = options["clear"] == "yes"
    user_cert = path_or_none(options["user-cert"])
    secure = path_or_none(options["secure"])
    pki = path_or_none(options["pki"])
    async def connect():
        client = Client(url, timeout=10)
        client.application_uri = "urn:pkm-plc-tests:asyncua"
        if user:
            client.set_user(user)
            client.set_password(password)
        if clear:
            asked = client.server_policy

            def in_clear(token_type):
                policy = asked(token_type)
                if token_type == ua.UserTokenType.UserName:
                    policy = dataclasses.replace(policy, SecurityPolicyUri=None)
                return policy

            client.server_policy = in_clear
        if user_cert:
            await client.load_client_certificate(str(user_cert / "cert.der"))
            await client.load_private_key(user_cert / "key.pem")
        if secure:
            cert, key = await client.setup_self_signed_certificate(secure / "key.pem", secure / "cert.der")
            await client.set_security(
                SecurityPolicyBasic256Sha256, str(cert), str(key), mode=ua.MessageSecurityMode.SignAndEncrypt
            )
        await client.connect()
        return client

    untrusted_first = False
    # The time from the first connection attempt to a session (the interpreter's start and the
    # imports not counted: on a busy machine they take seconds of their own).
    connecting = time.monotonic()
    try:
        try:
            client = await connect()
        except ua.uaerrors.BadCertificateUntrusted:
            if not pki:
                raise
            untrusted_first = True
            for rejected in (pki / "rejected").iterdir():
                shutil.move(str(rejected), str(pki / "trusted" / rejected.name))
            client = await connect()
    except ua.UaStatusCodeError as e:
        # A refused login (or channel): said, not raised.
        print(json.dumps({"untrusted_first": untrusted_first, "refused": type(e).__name__}))
        return
    connect_seconds = time.monotonic() - connecting
    out = []
    try:
        ns, root = await machine_node(client, machine)
        state = await child(root, ns, "State")
        for step in steps:
            if step.startswith("wait="):
                want = step[5:]
                deadline = time.time() + 30
                seen = await state.read_value()
                while seen != want and time.time() < deadline:
                    await asyncio.sleep(0.05)
                    seen = await state.read_value()
                out.append({"step": step, "state": seen})
                continue
            name, _, arg = step.partition("=")
            method = await child(root, ns, name)
            inputs = [ua.Variant(int(arg), ua.VariantType.Int16)] if arg else []
            try:
                result = await root.call_method(method, *inputs)
                out.append({"step": step, "status": "Good", "result": result})
            except ua.UaStatusCodeError as e:
                out.append({"step": step, "status": type(e).__name__})
    finally:
        await client.disconnect()
    print(json.dumps({"untrusted_first": untrusted_first, "connect_seconds": connect_seconds, "steps": out}))


async def endpoints(url):
    client = Client(url, timeout=10)
    out = []
    for e in await client.connect_and_get_server_endpoints():
        tokens = sorted(t.TokenType.name for t in e.UserIdentityTokens)
        out.append([e.SecurityPolicyUri.split("#")[-1], e.SecurityMode.name, tokens, e.EndpointUrl])
    print(json.dumps(out))


def connect_from(address):
    """Every connection this process opens from now on comes from the local `address`."""
    loop = asyncio.get_running_loop()
    original = loop.create_connection

    async def create_connection(*args, **kwargs):
        kwargs.setdefault("local_addr", (address, 0))
        return await original(*args, **kwargs)

    loop.create_connection = create_connection


async def hold(url, n, seconds, address):
    connect_from(address)
    clients = []
    for _ in range(n):
        client = Client(url, timeout=10)
        try:
            await client.connect()
            clients.append(client)
        except Exception:  # noqa: BLE001 - a refusal is counted, whatever its kind
            pass
    print(f"held {len(clients)}", flush=True)
    closed = {}
    end = time.time() + seconds
    alive = list(clients)
    while time.time() < end and alive:
        await asyncio.sleep(1)
        for client in list(alive):
            try:
                await client.nodes.server.read_attribute(ua.AttributeIds.BrowseName)
            except Exception as e:  # noqa: BLE001 - what the server said, whatever its kind
                alive.remove(client)
                closed[type(e).__name__] = closed.get(type(e).__name__, 0) + 1
    for client in alive:
        try:
            await client.disconnect()
        except Exception:  # noqa: BLE001
            pass
    print(json.dumps({"opened": len(clients), "closed": closed}))


async def abandon(url, n):
    opened, refused = 0, []
    for _ in range(n):
        client = Client(url, timeout=10)
        try:
            await client.connect_socket()
            await client.send_hello()
            await client.open_secure_channel()
            await client.create_session()
            await client.activate_session()
            opened += 1
        except ua.UaStatusCodeError as e:
            refused.append(type(e).__name__)
        finally:
            # The connection goes; the session stays on the server until it times out.
            client.disconnect_socket()
    print(json.dumps({"opened": opened, "refused": refused}))


async def channel(url, seconds):
    client = Client(url, timeout=5)
    await client.connect_socket()
    opened = time.time()
    await client.send_hello()
    await client.open_secure_channel()
    closed = False
    while time.time() - opened < seconds:
        await asyncio.sleep(0.5)
        try:
            params = ua.GetEndpointsParameters()
            params.EndpointUrl = url
            await client.uaclient.get_endpoints(params)
        except Exception:  # noqa: BLE001 - a closed connection fails whatever way it fails
            closed = True
            break
    lasted = time.time() - opened
    client.disconnect_socket()
    print(json.dumps({"lasted": lasted, "closed": closed}))


async def guess(url, user, count, parallel):
    refused = 0
    lock = asyncio.Semaphore(parallel)

    async def one(k):
        nonlocal refused
        async with lock:
            client = Client(url, timeout=20)
            client.set_user(user)
            client.set_password(f"wrong-guess-{k}")
            try:
                await client.connect()
                await client.disconnect()
            except ua.uaerrors.BadUserAccessDenied:
                refused += 1
            finally:
                client.disconnect_socket()

    start = time.time()
    await asyncio.gather(*(one(k) for k in range(count)))
    print(json.dumps({"refused": refused, "seconds": time.time() - start}))


async def usercert(directory):
    client = Client("opc.tcp://unused:4840")
    client.application_uri = "urn:pkm-plc-tests:cell-7"
    await client.setup_self_signed_certificate(directory / "key.pem", directory / "cert.der")
    print(json.dumps({"cert": str(directory / "cert.der")}))


class Alarms:
    """Collects the condition events of a subscription."""

    def __init__(self):
        self.events = []
        self.changed = asyncio.Event()

    def event_notification(self, event):
        fields = event.get_event_props_as_fields_dict()

        def value(name):
            v = fields.get(name)
            return None if v is None else v.Value

        message = value("Message")
        self.events.append(
            {
                "name": value("ConditionName"),
                "active": value("ActiveState/Id"),
                "acked": value("AckedState/Id"),
                "retain": value("Retain"),
                "message": message.Text if message is not None else None,
                "severity": value("Severity"),
                "type": ua.object_ids.ObjectIdNames.get(value("EventType").Identifier, str(value("EventType"))),
                "event_id": value("EventId"),
                "condition": value("NodeId"),
                "time": unix(value("Time")),
                "user": value("ClientUserId"),
            }
        )
        self.changed.set()

    def latest(self, name):
        for e in reversed(self.events):
            if e["name"] == name:
                return e
        return None


async def alarms(url, machine, args):
    """Subscribes to MACHINE's condition events and carries out STEPs in turn:
    refresh (ConditionRefresh for this subscription), a method of the machine (Stop, ...),
    wait=NAME:active|inactive|acked (an event of that condition so, within 30 s), ack=NAME
    (Acknowledge its latest event, comment "by the test"), sleep=SECONDS. JSON: every event
    received and each step's outcome."""
    options, steps = options_and_steps(args, ["user", "password"])
    user, password = options["user"], options["password"]
    client = Client(url, timeout=10)
    if user:
        client.set_user(user)
        client.set_password(password)
    out = {"steps": []}
    async with client:
        ns, root = await machine_node(client, machine)
        handler = Alarms()
        sub = await client.create_subscription(50, handler)
        await sub.subscribe_events(root, ua.ObjectIds.AlarmConditionType)
        for step in steps:
            entry = {"step": step}
            try:
                if step == "refresh":
                    condition_type = client.get_node(ua.ObjectIds.ConditionType)
                    await condition_type.call_method(
                        ua.NodeId(ua.ObjectIds.ConditionType_ConditionRefresh),
                        ua.Variant(sub.subscription_id, ua.VariantType.UInt32),
                    )
                    entry["status"] = "Good"
                elif step.startswith("wait="):
                    name, how = step[5:].split(":")
                    deadline = time.monotonic() + 30
                    field = {"active": ("active", True), "inactive": ("active", False), "acked": ("acked", True)}[how]

                    def met():
                        return any(e["name"] == name and e[field[0]] == field[1] for e in handler.events)

                    while not met() and time.monotonic() < deadline:
                        handler.changed.clear()
                        try:
                            await asyncio.wait_for(handler.changed.wait(), 1)
                        except asyncio.TimeoutError:
                            pass
                    entry["status"] = "Good" if met() else "Timeout"
                elif step.startswith("ack="):
                    latest = handler.latest(step[4:])
                    if latest is None:
                        entry["status"] = "NoEvent"
                    else:
                        condition = client.get_node(latest["condition"])
                        await condition.call_method(
                            ua.NodeId(ua.ObjectIds.AcknowledgeableConditionType_Acknowledge),
                            ua.Variant(latest["event_id"], ua.VariantType.ByteString),
                            ua.LocalizedText("by the test"),
                        )
                        entry["status"] = "Good"
                elif step.startswith("sleep="):
                    await asyncio.sleep(float(step[6:]))
                    entry["status"] = "Good"
                else:
                    method = await child(root, ns, step)
                    await root.call_method(method)
                    entry["status"] = "Good"
            except ua.UaStatusCodeError as e:
                entry["status"] = type(e).__name__
            out["steps"].append(entry)
        await sub.delete()
    for e in handler.events:
        e["event_id"] = e["event_id"].decode("utf-8", "replace") if e["event_id"] else None
        e["condition"] = e["condition"].to_string() if e["condition"] else None
    out["events"] = handler.events
    print(json.dumps(out))


async def history(url, machine, name, seconds, part):
    """Reads the raw history of MACHINE's variable NAME (MainState, BusFault, or a process-image
    variable) over the last SECONDS: whole, and again PART values a read, following the
    continuation points. JSON: the values as [time, value], the reads the parts took and how
    many values they gave."""
    async with Client(url, timeout=10) as client:
        ns, root = await machine_node(client, machine)
        node = None
        if name in ("MainState", "BusFault"):
            node = await child(root, ns, name)
        else:
            for cls in await (await child(root, ns, "TaskClasses")).get_children():
                try:
                    node = await cls.get_child([f"{ns}:Variables", f"{ns}:{name}"])
                    break
                except ua.UaStatusCodeError:
                    continue
        end = datetime.datetime.now(datetime.timezone.utc)
        start = end - datetime.timedelta(seconds=seconds)
        values = await node.read_raw_history(start, end)
        details = ua.ReadRawModifiedDetails()
        details.IsReadModified = False
        details.StartTime = start
        details.EndTime = end
        details.NumValuesPerNode = part
        details.ReturnBounds = False
        reads, total, cp = 0, 0, None
        while True:
            result = await node.history_read(details, cp)
            result.StatusCode.check()
            reads += 1
            total += len(result.HistoryData.DataValues)
            cp = result.ContinuationPoint
            if cp is None or reads > 10000:
                break
        print(
            json.dumps(
                {
                    "values": [[unix(v.SourceTimestamp), v.Value.Value] for v in values],
                    "reads": reads,
                    "in_parts": total,
                }
            )
        )


MANDATORY = ua.NodeId(ua.ObjectIds.ModellingRule_Mandatory)
PLACEHOLDERS = {ua.NodeId(ua.ObjectIds.ModellingRule_OptionalPlaceholder), ua.NodeId(ua.ObjectIds.ModellingRule_MandatoryPlaceholder)}
CHILD_REFS = {ua.NodeId(ua.ObjectIds.HasComponent), ua.NodeId(ua.ObjectIds.HasProperty), ua.NodeId(ua.ObjectIds.HasAddIn)}


class TypeChecker:
    """Checks instances against the type definitions the server serves (cached per node)."""

    def __init__(self, client, namespaces):
        self.client = client
        self.namespaces = namespaces
        self.cache = {}
        self.out = {"nodes": 0, "declarations": 0, "missing": [], "wrong": [], "untyped": []}

    def name(self, qn):
        return f"{self.namespaces[qn.NamespaceIndex]}:{qn.Name}"

    async def children(self, node_id):
        """(reference type, child node id, browse name, node class) of node_id's forward components, properties and add-ins."""
        key = ("children", node_id)
        if key not in self.cache:
            refs = await self.client.get_node(node_id).get_references(refs=ua.ObjectIds.HierarchicalReferences, direction=ua.BrowseDirection.Forward, includesubtypes=True)
            self.cache[key] = [(r.ReferenceTypeId, r.NodeId, r.BrowseName, r.NodeClass) for r in refs if r.ReferenceTypeId in CHILD_REFS]
        return self.cache[key]

    async def one_ref(self, node_id, ref, forward=True):
        key = ("ref", node_id, ref, forward)
        if key not in self.cache:
            refs = await self.client.get_node(node_id).get_references(refs=ref, direction=ua.BrowseDirection.Forward if forward else ua.BrowseDirection.Inverse, includesubtypes=False)
            self.cache[key] = refs[0].NodeId if refs else None
        return self.cache[key]

    async def supertype(self, type_id):
        return await self.one_ref(type_id, ua.ObjectIds.HasSubtype, forward=False)

    async def is_subtype(self, sub, sup):
        while sub is not None:
            if sub == sup:
                return True
            sub = await self.supertype(sub)
        return False

    async def data_type(self, node_id):
        key = ("dt", node_id)
        if key not in self.cache:
            self.cache[key] = await self.client.get_node(node_id).read_data_type()
        return self.cache[key]

    async def declarations(self, type_id):
        """The type's and its supertypes' instance declarations, the most derived first for each browse name: (browse name, node id, node class, rule)."""
        seen, out = set(), []
        t = type_id
        while t is not None:
            for _, child, bn, nc in await self.children(t):
                if (bn.NamespaceIndex, bn.Name) in seen:
                    continue
                seen.add((bn.NamespaceIndex, bn.Name))
                out.append((bn, child, nc, await self.one_ref(child, ua.ObjectIds.HasModellingRule)))
            t = await self.supertype(t)
        return out

    async def check_against(self, path, instance, decls, type_checked):
        """Checks `instance` against declarations `decls` (its type's, or a declaration's own children)."""
        kids = await self.children(instance)
        by_name = {(bn.NamespaceIndex, bn.Name): (child, nc) for _, child, bn, nc in kids}
        for bn, decl, nc, rule in decls:
            if rule != MANDATORY:
                continue
            self.out["declarations"] += 1
            where = f"{path}/{self.name(bn)}"
            found = by_name.get((bn.NamespaceIndex, bn.Name))
            if found is None:
                self.out["missing"].append(where)
                continue
            child, child_nc = found
            if child_nc != nc:
                self.out["wrong"].append(f"{where}: a {child_nc.name}, declared a {nc.name}")
                continue
            decl_type = await self.one_ref(decl, ua.ObjectIds.HasTypeDefinition)
            child_type = await self.one_ref(child, ua.ObjectIds.HasTypeDefinition)
            if decl_type is not None and not await self.is_subtype(child_type, decl_type):
                self.out["wrong"].append(f"{where}: of type {child_type}, declared {decl_type}")
            if nc == ua.NodeClass.Variable:
                decl_dt, child_dt = await self.data_type(decl), await self.data_type(child)
                if not await self.is_subtype(child_dt, decl_dt):
                    self.out["wrong"].append(f"{where}: data type {child_dt}, declared {decl_dt}")
            # The declaration's own children, then the child against its own type.
            await self.check_against(where, child, [(b, c, n, await self.one_ref(c, ua.ObjectIds.HasModellingRule)) for _, c, b, n in await self.children(decl)], type_checked)
            await self.check(where, child, type_checked)

    async def check(self, path, instance, type_checked):
        if instance in type_checked:
            return
        type_checked.add(instance)
        self.out["nodes"] += 1
        node_class = await self.client.get_node(instance).read_node_class()
        type_id = await self.one_ref(instance, ua.ObjectIds.HasTypeDefinition)
        if type_id is None:
            if node_class in (ua.NodeClass.Object, ua.NodeClass.Variable):
                self.out["untyped"].append(path)
            return
        await self.check_against(path, instance, await self.declarations(type_id), type_checked)
        # Placeholders' instances and other children of a companion's type: against their own type.
        for _, child, bn, nc in await self.children(instance):
            child_type = await self.one_ref(child, ua.ObjectIds.HasTypeDefinition)
            if child_type is not None and child_type.NamespaceIndex not in (0, self.namespaces.index(NS)):
                await self.check(f"{path}/{self.name(bn)}", child, type_checked)

    async def untyped_below(self, root, depth=0):
        """Objects below root (in our namespace's hierarchy) without a type definition."""
        for _, child, bn, nc in await self.children(root) + [(None, r.NodeId, r.BrowseName, r.NodeClass) for r in await self.client.get_node(root).get_references(refs=ua.ObjectIds.Organizes, direction=ua.BrowseDirection.Forward)]:
            if nc != ua.NodeClass.Object or child.NamespaceIndex != self.namespaces.index(NS) or ("seen", child) in self.cache:
                continue
            self.cache[("seen", child)] = True
            if await self.one_ref(child, ua.ObjectIds.HasTypeDefinition) is None:
                self.out["untyped"].append(self.name(bn))
            if depth < 6:
                await self.untyped_below(child, depth + 1)


async def typecheck(url, node_id):
    async with Client(url, timeout=20) as client:
        namespaces = await client.get_namespace_array()
        checker = TypeChecker(client, namespaces)
        root = ua.NodeId.from_string(node_id.replace("ns=2;", f"ns={namespaces.index(NS)};"))
        await checker.check(node_id, root, set())
        await checker.untyped_below(ua.NodeId(ua.ObjectIds.ObjectsFolder))
        typedef = await checker.one_ref(root, ua.ObjectIds.HasTypeDefinition)
        checker.out["type"] = f"{namespaces[typedef.NamespaceIndex]}:{await browse_name_of(client, typedef)}"
        print(json.dumps(checker.out))


async def machine_tool(url, machine):
    mt_uri = "http://opcfoundation.org/UA/MachineTool/"
    async with Client(url, timeout=10) as client:
        namespaces = await client.get_namespace_array()
        ns, mt = namespaces.index(NS), namespaces.index(mt_uri)
        node = await client.nodes.objects.get_child([f"{ns}:PkmPlc", f"{ns}:{machine}"])
        typedef = await node.read_type_definition()

        async def value(*path):
            v = await (await node.get_child(list(path))).read_value()
            return v.Text if isinstance(v, ua.LocalizedText) else v

        out = {
            "type": f"{namespaces[typedef.NamespaceIndex]}:{await browse_name_of(client, typedef)}",
            "operation_mode": await value(f"{mt}:Monitoring", f"{mt}:MachineTool", f"{mt}:OperationMode"),
            "channel_state": await value(f"{mt}:Monitoring", f"{mt}:Channel1", f"{mt}:ChannelState"),
            "channel_mode": await value(f"{mt}:Monitoring", f"{mt}:Channel1", f"{mt}:ChannelMode"),
            "feed_override": await value(f"{mt}:Monitoring", f"{mt}:Channel1", f"{mt}:FeedOverride"),
            "spindle_rotating": await value(f"{mt}:Monitoring", f"{mt}:Spindle", f"{mt}:IsRotating"),
            "program": await value(f"{mt}:Production", f"{mt}:ActiveProgram", f"{mt}:Name"),
            "program_state": await value(f"{mt}:Production", f"{mt}:ActiveProgram", f"{mt}:State", "0:CurrentState"),
            "job_state": await value(f"{mt}:Production", f"{mt}:ProductionPlan", f"{ns}:Job", f"{mt}:State", "0:CurrentState"),
            "runs_completed": await value(f"{mt}:Production", f"{mt}:ProductionPlan", f"{ns}:Job", f"{mt}:RunsCompleted"),
            "runs_planned": await value(f"{mt}:Production", f"{mt}:ProductionPlan", f"{ns}:Job", f"{mt}:RunsPlanned"),
            "prognoses": {},
            "tools": {},
            "read_at": time.time(),
        }
        prognoses = await node.get_child([f"{mt}:Notification", f"{mt}:Prognoses"])
        for p in await prognoses.get_children(refs=ua.ObjectIds.HasComponent):
            name = (await p.read_browse_name()).Name
            fields = {}
            for child in await p.get_children():
                v = await child.read_value()
                if isinstance(v, ua.LocalizedText):
                    v = v.Text
                elif isinstance(v, datetime.datetime):
                    v = unix(v)
                fields[(await child.read_browse_name()).Name] = v
            out["prognoses"][name] = fields
        tools = await node.get_child([f"{mt}:Equipment", f"{mt}:Tools"])
        for t in await tools.get_children(refs=ua.ObjectIds.HasComponent):
            name = (await t.read_browse_name()).Name
            out["tools"][name] = {
                "name": await (await t.get_child([f"{mt}:Name"])).read_value(),
                "number": await (await t.get_child([f"{mt}:ControlIdentifier1"])).read_value(),
            }
        print(json.dumps(out))


async def messages(url, machine, seconds):
    mt_uri = "http://opcfoundation.org/UA/MachineTool/"
    async with Client(url, timeout=10) as client:
        namespaces = await client.get_namespace_array()
        ns, mt = namespaces.index(NS), namespaces.index(mt_uri)
        node = await client.nodes.objects.get_child([f"{ns}:PkmPlc", f"{ns}:{machine}", f"{mt}:Notification", f"{mt}:Messages"])
        subscription = await client.create_subscription(100, EventPrinter())
        alarm_type = client.get_node(ua.ObjectIds.AlarmConditionType)
        await subscription.subscribe_events(node, alarm_type)
        print("subscribed", flush=True)
        await asyncio.sleep(seconds)


class EventPrinter:
    """Prints each event as a JSON line as it comes: its condition name and whether active."""

    def event_notification(self, event):
        fields = event.get_event_props_as_fields_dict()
        name = fields.get("ConditionName")
        active = fields.get("ActiveState/Id")
        line = {"name": name.Value if name is not None else None, "active": active.Value if active is not None else None}
        print(json.dumps(line), flush=True)


async def browse_name_of(client, node_id):
    """The browse name (without its namespace) of the node `node_id`."""
    return (await client.get_node(node_id).read_browse_name()).Name


async def machinery(url, machine):
    machinery_uri = "http://opcfoundation.org/UA/Machinery/"
    di_uri = "http://opcfoundation.org/UA/DI/"
    async with Client(url, timeout=10) as client:
        namespaces = await client.get_namespace_array()
        ns = namespaces.index(NS)
        m = namespaces.index(machinery_uri)
        di = namespaces.index(di_uri)
        out = {"namespaces": namespaces, "tree": []}
        machines = await client.nodes.objects.get_child([f"{m}:Machines"])
        out["machines"] = [(await c.read_browse_name()).Name for c in await machines.get_children()]
        node = await client.nodes.objects.get_child([f"{m}:Machines", f"{ns}:{machine}"])
        out["tree"].append(f"Objects/Machines/{machine}")
        ident = await node.get_child([f"{di}:Identification"])
        out["identification_type"] = await browse_name_of(client, await ident.read_type_definition())
        out["identification"] = {}
        out["tree"].append(f"  Identification ({out['identification_type']})")
        for prop in await ident.get_properties():
            name = await prop.read_browse_name()
            value = await prop.read_value()
            if isinstance(value, ua.LocalizedText):
                value = value.Text
            out["identification"][f"{namespaces[name.NamespaceIndex]}{name.Name}"] = value
            out["tree"].append(f"    {name.Name} = {value!r}")
        blocks = await node.get_child([f"{m}:MachineryBuildingBlocks"])
        out["tree"].append("  MachineryBuildingBlocks")
        add_ins = await blocks.get_referenced_nodes(refs=ua.ObjectIds.HasAddIn)
        out["building_blocks"] = sorted([(await a.read_browse_name()).Name for a in add_ins])
        for name in ["MachineryItemState", "MachineryOperationMode"]:
            sm = await blocks.get_child([f"{m}:{name}"])
            current = await sm.get_child(["0:CurrentState"])
            state_id = await (await current.get_child(["0:Id"])).read_value()
            entry = {
                "type": await browse_name_of(client, await sm.read_type_definition()),
                "current": (await current.read_value()).Text,
                "id": await browse_name_of(client, state_id),
                "id_namespace": namespaces[state_id.NamespaceIndex],
                "number": await (await current.get_child(["0:Number"])).read_value(),
            }
            out[name] = entry
            out["tree"].append(
                f"    {name} ({entry['type']}): CurrentState = {entry['current']!r}, Number = {entry['number']}"
            )
        # The PLC's state and both Machinery states in one Read: the values of one frame.
        state = await child(await client.nodes.objects.get_child([f"{ns}:PkmPlc", f"{ns}:{machine}"]), ns, "State")
        item = await blocks.get_child([f"{m}:MachineryItemState", "0:CurrentState"])
        mode = await blocks.get_child([f"{m}:MachineryOperationMode", "0:CurrentState"])
        plc, item_now, mode_now = await client.read_values([state, item, mode])
        out["together"] = [plc, item_now.Text, mode_now.Text]
        for add_in in out["building_blocks"]:
            if add_in not in ("MachineryItemState", "MachineryOperationMode"):
                out["tree"].append(f"    {add_in} (HasAddIn)")
        print(json.dumps(out))


def main():
    cmd, *rest = sys.argv[1:]
    if cmd == "endpoints":
        asyncio.run(endpoints(rest[0]))
        return
    if cmd == "usercert":
        asyncio.run(usercert(Path(rest[0])))
        return
    if cmd == "abandon":
        asyncio.run(abandon(rest[0], int(rest[1])))
        return
    if cmd == "hold":
        asyncio.run(hold(rest[0], int(rest[1]), float(rest[2]), rest[3]))
        return
    if cmd == "channel":
        asyncio.run(channel(rest[0], float(rest[1])))
        return
    if cmd == "guess":
        asyncio.run(guess(rest[0], rest[1], int(rest[2]), int(rest[3])))
        return
    if cmd == "typecheck":
        asyncio.run(typecheck(rest[0], rest[1]))
        return
    url, machine, *rest = rest
    if cmd == "machine_tool":
        asyncio.run(machine_tool(url, machine))
        return
    if cmd == "messages":
        asyncio.run(messages(url, machine, float(rest[0])))
        return
    if cmd == "survey":
        asyncio.run(survey(url, machine))
    elif cmd == "subscribe":
        asyncio.run(subscribe(url, machine, float(rest[0]), "all" in rest[1:], "events" in rest[1:]))
    elif cmd == "call":
        asyncio.run(call(url, machine, rest))
    elif cmd == "alarms":
        asyncio.run(alarms(url, machine, rest))
    elif cmd == "machinery":
        asyncio.run(machinery(url, machine))
    elif cmd == "history":
        asyncio.run(history(url, machine, rest[0], float(rest[1]), int(rest[2])))
    else:
        sys.exit(f"unknown command {cmd}")


if __name__ == "__main__":
    main()
