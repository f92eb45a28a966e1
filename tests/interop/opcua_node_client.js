// A second OPC UA client nobody here wrote: node-opcua's (the stack behind Node-RED's OPC UA
// nodes), from npm, against `pkm-plc run --opcua`. Its client checks by default that the
// endpoint it connects to is one the server advertises (`endpointMustExist`), so it connects
// only where the server advertises the host and port the client used.
//
//   node opcua_node_client.js read URL MACHINE [--secure DIR --pki SERVER_PKI]
//       Connects with node-opcua's defaults (None security; with --secure, Basic256Sha256
//       SignAndEncrypt with a client certificate kept in DIR: a first connection is refused as
//       untrusted, the certificate the server put into SERVER_PKI/rejected/ is moved to
//       trusted/ as an administrator would, and it connects again), opens an anonymous session
//       and reads PkmPlc/MACHINE/State. JSON on the last line of stdout: "state", the
//       advertised "endpoints" (URL, policy, mode), "machinery" (the machine's Model and
//       MachineryItemState found by browse path from Objects/Machines), "machine_tool" (the
//       OPC 40501-1 building blocks' types and the operation mode, channel state, feed override,
//       program state and manufacturer, by browse paths), "untrusted_first" with --secure.
//
// Exit 1 with the error on stderr where it cannot connect.

"use strict";

const fs = require("fs");
const path = require("path");
const { OPCUACertificateManager } = require("node-opcua-certificate-manager");
const {
    OPCUAClient,
    MessageSecurityMode,
    SecurityPolicy,
    AttributeIds,
    makeBrowsePath,
} = require("node-opcua-client");

const NS = "urn:pkm-plc";

function options(secure) {
    const o = {
        applicationName: "pkm-plc interop (node-opcua)",
        // Fail at once: node-opcua retries forever by default.
        connectionStrategy: { maxRetry: 0, initialDelay: 100, maxDelay: 200 },
        requestedSessionTimeout: 60000,
    };
    if (secure) {
        o.securityMode = MessageSecurityMode.SignAndEncrypt;
        o.securityPolicy = SecurityPolicy.Basic256Sha256;
        o.clientCertificateManager = new OPCUACertificateManager({
            rootFolder: secure,
            automaticallyAcceptUnknownCertificate: true,
        });
    }
    return o;
}

async function readState(url, machine, secure) {
    const client = OPCUAClient.create(options(secure));
    await client.connect(url);
    try {
        const endpoints = (await client.getEndpoints()).map((e) => [
            e.endpointUrl,
            e.securityPolicyUri.split("#").pop(),
            MessageSecurityMode[e.securityMode],
        ]);
        const session = await client.createSession();
        try {
            const namespaces = (await session.read({ nodeId: "ns=0;i=2255", attributeId: AttributeIds.Value })).value
                .value;
            const ns = namespaces.indexOf(NS);
            if (ns < 0) throw new Error(`no namespace ${NS}: ${namespaces}`);
            const found = await session.translateBrowsePath(
                makeBrowsePath("RootFolder", `/Objects/${ns}:PkmPlc/${ns}:${machine}/${ns}:State`),
            );
            const target = (found.targets || [])[0];
            if (!target) throw new Error(`no State: ${found.statusCode.toString()}`);
            const state = await session.read({ nodeId: target.targetId, attributeId: AttributeIds.Value });
            // The machine as an MES finds it: Machinery's Machines folder, by browse path
            // through DI's and Machinery's namespaces.
            const di = namespaces.indexOf("http://opcfoundation.org/UA/DI/");
            const m = namespaces.indexOf("http://opcfoundation.org/UA/Machinery/");
            const machinery = {};
            for (const [name, browse] of [
                ["model", `${di}:Identification/${di}:Model`],
                ["item_state", `${m}:MachineryBuildingBlocks/${m}:MachineryItemState/0:CurrentState`],
            ]) {
                const at = await session.translateBrowsePath(
                    makeBrowsePath("RootFolder", `/Objects/${m}:Machines/${ns}:${machine}/${browse}`),
                );
                const node = (at.targets || [])[0];
                if (!node) throw new Error(`no ${browse}: ${at.statusCode.toString()}`);
                const value = await session.read({ nodeId: node.targetId, attributeId: AttributeIds.Value });
                machinery[name] = value.value.value.text;
            }
            // The machine tool (OPC 40501-1), as umati reads it: the building blocks with their
            // types, and the values, by browse paths through the Machine Tools namespace.
            const mt = namespaces.indexOf("http://opcfoundation.org/UA/MachineTool/");
            const machineTool = { types: {}, values: {} };
            const at = async (browse) => {
                const found = await session.translateBrowsePath(
                    makeBrowsePath("RootFolder", `/Objects/${m}:Machines/${ns}:${machine}${browse}`),
                );
                const node = (found.targets || [])[0];
                if (!node) throw new Error(`no ${browse}: ${found.statusCode.toString()}`);
                return node.targetId;
            };
            const typeName = async (nodeId) => {
                const refs = await session.browse({
                    nodeId,
                    referenceTypeId: "i=40",
                    includeSubtypes: false,
                    // Forward.
                    browseDirection: 0,
                    resultMask: 63,
                });
                const type = (refs.references || [])[0];
                return type ? `${namespaces[type.nodeId.namespace]}:${type.browseName.name}` : null;
            };
            machineTool.types.machine = await typeName(await at(""));
            for (const [name, browse] of [
                ["identification", `/${di}:Identification`],
                ["monitoring", `/${mt}:Monitoring`],
                ["channel", `/${mt}:Monitoring/${mt}:Channel1`],
                ["production", `/${mt}:Production`],
                ["active_program", `/${mt}:Production/${mt}:ActiveProgram`],
                ["notification", `/${mt}:Notification`],
                ["equipment", `/${mt}:Equipment`],
            ]) {
                machineTool.types[name] = await typeName(await at(browse));
            }
            for (const [name, browse] of [
                ["operation_mode", `/${mt}:Monitoring/${mt}:MachineTool/${mt}:OperationMode`],
                ["channel_state", `/${mt}:Monitoring/${mt}:Channel1/${mt}:ChannelState`],
                ["feed_override", `/${mt}:Monitoring/${mt}:Channel1/${mt}:FeedOverride`],
                ["program_state", `/${mt}:Production/${mt}:ActiveProgram/${mt}:State/0:CurrentState`],
                ["manufacturer", `/${di}:Identification/${di}:Manufacturer`],
            ]) {
                const value = (await session.read({ nodeId: await at(browse), attributeId: AttributeIds.Value })).value
                    .value;
                machineTool.values[name] = value && value.text !== undefined ? value.text : value;
            }
            return { state: state.value.value, endpoints, machinery, machine_tool: machineTool };
        } finally {
            await session.close();
        }
    } finally {
        await client.disconnect();
    }
}

/// Moves the certificates the server rejected into its trusted store.
function trustRejected(pki) {
    const rejected = path.join(pki, "rejected");
    const trusted = path.join(pki, "trusted");
    fs.mkdirSync(trusted, { recursive: true });
    let moved = 0;
    for (const name of fs.existsSync(rejected) ? fs.readdirSync(rejected) : []) {
        fs.renameSync(path.join(rejected, name), path.join(trusted, name));
        moved += 1;
    }
    return moved;
}

async function main() {
    const [command, url, machine, ...rest] = process.argv.slice(2);
    if (command !== "read" || !url || !machine) {
        throw new Error("usage: opcua_node_client.js read URL MACHINE [--secure DIR --pki SERVER_PKI]");
    }
    const flag = (name) => {
        const i = rest.indexOf(name);
        return i >= 0 ? rest[i + 1] : undefined;
    };
    const secure = flag("--secure");
    const pki = flag("--pki");
    if (!secure) {
        console.log(JSON.stringify(await readState(url, machine, undefined)));
        return;
    }
    let untrustedFirst = false;
    try {
        const out = await readState(url, machine, secure);
        console.log(JSON.stringify({ ...out, untrusted_first: false }));
        return;
    } catch (e) {
        untrustedFirst = true;
        if (!pki || trustRejected(pki) === 0) throw e;
    }
    const out = await readState(url, machine, secure);
    console.log(JSON.stringify({ ...out, untrusted_first: untrustedFirst }));
}

main().then(
    () => process.exit(0),
    (e) => {
        console.error(e && e.stack ? e.stack : String(e));
        process.exit(1);
    },
);
