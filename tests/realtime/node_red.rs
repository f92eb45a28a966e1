//! A lab's gateway as it is built: Node-RED with node-red-contrib-opcua (from npm, installed
//! under `target/`; skipped and said why without npm or the registry), run headless with a flow
//! of 20 OPC UA nodes against the PLC started with the default OPC UA options. The contrib's
//! nodes each open a connection and a session of their own, all from one host: 16 read a
//! variable, 2 subscribe, 1 receives the alarm events, 1 logs in as a user and calls Stop. Every
//! one of them must get its answer: with the earlier bound of 7 connections per host, the eighth
//! node and those after it were refused.

use std::path::Path;
use std::time::{Duration, Instant};

use serde_json::{Value as Json, json};

use crate::common;

/// The variables the flow's read nodes read, below the machine (`ns=2;s=trijoint.…`).
const READ: [&str; 16] = [
    "State",
    "MainState",
    "Reason",
    "Note",
    "BusFault",
    "TOOL_X",
    "TOOL_Y",
    "setpoint_right_mm",
    "setpoint_left_mm_s",
    "TaskClasses.fast.Cycles",
    "TaskClasses.main.Cycles",
    "TaskClasses.spare.Cycles",
    "TaskClasses.fast.CycleTimeMs",
    "TaskClasses.main.CycleTimeMs",
    "TaskClasses.fast.Overruns",
    "TaskClasses.main.Violations",
];

/// The variables the flow's subscribe nodes subscribe to.
const SUBSCRIBED: [&str; 2] = ["MainState", "TaskClasses.main.Cycles"];

/// A function node that writes what `name` sends as one JSON line: from its results output
/// (`results`) or from its status output (the contrib's second output: its status changes, and
/// its errors with `error` set).
fn tagger(id: &str, name: &str, results: bool) -> Json {
    let func = format!(
        r#"const safe = (k, v) => typeof v === "bigint" ? v.toString() : v;
let value = null;
try {{ value = JSON.parse(JSON.stringify(msg.payload, safe)); }} catch (e) {{ value = String(msg.payload); }}
const code = msg.statusCode || (msg.result && msg.result.statusCode);
const status = code ? String(code.name || code) : (msg.status ? String(msg.status) : null);
const error = msg.error ? String(msg.error.message || msg.error) : null;
msg.payload = JSON.stringify({{node: {name:?}, results: {results}, topic: String(msg.topic || ""), value, status, error}});
return msg;"#
    );
    json!({"id": id, "type": "function", "z": "flow", "name": format!("tag {name}"),
        "func": func, "outputs": 1, "wires": [["n-out"]]})
}

/// An OPC UA client node `name` doing `action` on `endpoint`, with the editor's defaults.
fn client(id: &str, name: &str, action: &str, endpoint: &str, time_ms: u32) -> Json {
    json!({"id": id, "type": "OpcUa-Client", "z": "flow", "endpoint": endpoint, "action": action,
        "deadbandtype": "a", "deadbandvalue": 1, "time": time_ms, "timeUnit": "ms",
        "certificate": "n", "localfile": "", "localkeyfile": "", "securitymode": "None",
        "securitypolicy": "None", "useTransport": false, "maxChunkCount": 1,
        "maxMessageSize": 8192, "receiveBufferSize": 8192, "sendBufferSize": 8192,
        "setstatusandtime": false, "keepsessionalive": false, "name": name,
        "applicationName": "", "applicationUri": "",
        "wires": [[format!("{id}-results")], [format!("{id}-status")], []]})
}

/// An inject node that fires `delay_s` after the flow starts, and then every `repeat_s` unless
/// empty, with `payload` (a number: the contrib reads a subscription's interval from it).
fn inject(id: &str, delay_s: f64, repeat_s: &str, payload: &str, to: &str) -> Json {
    json!({"id": id, "type": "inject", "z": "flow", "once": true, "onceDelay": delay_s,
        "repeat": repeat_s, "topic": "", "payload": payload, "payloadType": "num",
        "props": [{"p": "payload"}], "wires": [[to]]})
}

/// The flow: [`READ`], [`SUBSCRIBED`], the alarm events and Stop, against `url`, every result
/// appended to `out` as a JSON line.
fn flow(url: &str, out: &Path) -> Json {
    let endpoint = |id: &str, login: bool| {
        json!({"id": id, "type": "OpcUa-Endpoint", "endpoint": url, "secpol": "None",
            "secmode": "None", "none": !login, "login": login, "usercert": false,
            "usercertificate": "", "userprivatekey": ""})
    };
    let mut nodes = vec![
        json!({"id": "flow", "type": "tab", "label": "pkm-plc"}),
        endpoint("n-anonymous", false),
        endpoint("n-operator", true),
        json!({"id": "n-out", "type": "file", "z": "flow", "filename": out.to_str().expect("utf-8"),
            "filenameType": "str", "appendNewline": true, "createDir": false,
            "overwriteFile": "false", "encoding": "none", "wires": [[]]}),
    ];
    let mut item_client = |kind: &str, k: usize, name: &str, action: &str, repeat_s: &str| {
        let id = format!("n-{kind}{k}");
        nodes.push(inject(
            &format!("{id}-inject"),
            2.0,
            repeat_s,
            "100",
            &format!("{id}-item"),
        ));
        nodes.push(json!({"id": format!("{id}-item"), "type": "OpcUa-Item", "z": "flow",
            "item": format!("ns=2;s=trijoint.{name}"), "datatype": "", "value": "", "name": name,
            "wires": [[id.clone()]]}));
        nodes.push(client(&id, &format!("{kind} {name}"), action, "n-anonymous", 100));
        nodes.push(tagger(&format!("{id}-results"), &format!("{kind} {name}"), true));
        nodes.push(tagger(&format!("{id}-status"), &format!("{kind} {name}"), false));
    };
    for (k, name) in READ.iter().enumerate() {
        // Read every 2 s, as a dashboard polls.
        item_client("read", k, name, "read", "2");
    }
    for (k, name) in SUBSCRIBED.iter().enumerate() {
        item_client("subscribe", k, name, "subscribe", "");
    }
    // The alarm events of the machine's object (AlarmConditionType and its subtypes).
    nodes.push(inject("n-events-inject", 2.0, "", "100", "n-events-type"));
    nodes.push(json!({"id": "n-events-type", "type": "OpcUa-Event", "z": "flow",
        "root": "ns=2;s=trijoint", "activatecustomevent": false, "eventtype": "i=2915",
        "customeventtype": "", "name": "alarms", "wires": [["n-events"]]}));
    nodes.push(client("n-events", "events", "events", "n-anonymous", 100));
    nodes.push(tagger("n-events-results", "events", true));
    nodes.push(tagger("n-events-status", "events", false));
    // Stop, by the operator, once the others are served.
    nodes.push(inject("n-stop-inject", 10.0, "", "0", "n-stop"));
    nodes.push(
        json!({"id": "n-stop", "type": "OpcUa-Method", "z": "flow", "endpoint": "n-operator",
        "objectId": "ns=2;s=trijoint", "methodId": "ns=2;s=trijoint.Stop", "name": "Stop",
        "inputArguments": [], "outputArguments": [],
        "arg0name": "", "arg0type": "", "arg0typeid": "", "arg0value": "",
        "arg1name": "", "arg1type": "", "arg1typeid": "", "arg1value": "",
        "arg2name": "", "arg2type": "", "arg2typeid": "", "arg2value": "",
        "out0name": "", "out0type": "", "wires": [["n-stop-results"]]}),
    );
    nodes.push(tagger("n-stop-results", "Stop", true));
    Json::Array(nodes)
}

/// The lines written so far, parsed.
fn lines(out: &Path) -> Vec<Json> {
    std::fs::read_to_string(out)
        .unwrap_or_default()
        .lines()
        .filter_map(|l| serde_json::from_str(l).ok())
        .collect()
}

/// What the flow has to show for the test to end: every read answered, both subscriptions
/// updated (the cycle counter at least 10 times, the main state to ERROR = 4), Stop called, and
/// the Stop alarm received.
fn complete(got: &[Json]) -> bool {
    let answered = |node: &str| got.iter().filter(|l| l["node"] == node && l["results"] == true).count();
    READ.iter().all(|name| answered(&format!("read {name}")) >= 1)
        && answered("subscribe TaskClasses.main.Cycles") >= 10
        && got
            .iter()
            .any(|l| l["node"] == "subscribe MainState" && l["results"] == true && l["value"] == 4)
        && answered("Stop") >= 1
        && got
            .iter()
            .any(|l| l["node"] == "events" && l["value"]["ConditionName"] == "Stop")
}

/// The errors the nodes said, but for a node asked before its connection was made (Node-RED
/// starts every node at once; the read nodes ask again every 2 s).
fn errors(got: &[Json]) -> Vec<&Json> {
    got.iter()
        .filter(|l| l["error"].is_string() && l["error"] != "can't work without OPC UA client")
        .collect()
}

#[test]
fn a_node_red_flow_of_20_opc_ua_nodes_on_one_host_reads_subscribes_stops_and_gets_the_alarm() {
    let name = "node_red::a_node_red_flow_of_20_opc_ua_nodes_on_one_host_reads_subscribes_stops_and_gets_the_alarm";
    let modules = match common::node_red_interop() {
        Ok(modules) => modules,
        Err(why) => {
            common::skip(name, &why);
            return;
        }
    };
    let dir = tempfile::tempdir().expect("tempdir");
    let users = dir.path().join("users.json");
    {
        use std::os::unix::fs::PermissionsExt;
        std::fs::write(
            &users,
            r#"{"users": [{"name": "operator", "password": "a-long-passphrase"}]}"#,
        )
        .expect("users");
        std::fs::set_permissions(&users, std::fs::Permissions::from_mode(0o600)).expect("chmod");
    }
    let config = common::write_busy_machine_config(dir.path());
    // The default OPC UA options but for the users (Stop needs one) and a free port.
    let mut command = common::pkm_command();
    command
        .args(["run", "--config", config.to_str().expect("utf-8")])
        .args(["--hmi", "none", "--joystick", "none", "--duration", "120"])
        .args(["--opcua", "opc.tcp://127.0.0.1:0"])
        .args(["--opcua-users", users.to_str().expect("utf-8")])
        .env("RUST_LOG", "info");
    let (plc, announced) = common::Logged::start(command, "OPC UA server at ", Duration::from_secs(60));
    let port = announced.rsplit(':').next().unwrap_or_default().trim_end_matches('/');
    let url = format!("opc.tcp://127.0.0.1:{port}/");
    plc.wait_for_state(0, "READY", Duration::from_secs(60));

    // Node-RED's own directory: the flow, the operator's credentials in clear (no secret set),
    // settings that open no editor, and the installed nodes.
    let user_dir = dir.path().join("node-red");
    std::fs::create_dir(&user_dir).expect("user dir");
    let out = dir.path().join("results.jsonl");
    let flow_file = user_dir.join("flows.json");
    std::fs::write(&flow_file, flow(&url, &out).to_string()).expect("flow");
    std::fs::write(
        user_dir.join("flows_cred.json"),
        json!({"n-operator": {"user": "operator", "password": "a-long-passphrase"}}).to_string(),
    )
    .expect("credentials");
    std::fs::write(
        user_dir.join("settings.js"),
        "module.exports = { uiHost: '127.0.0.1', uiPort: 0, httpAdminRoot: false, httpNodeRoot: false,\n\
         credentialSecret: false, flowFile: 'flows.json', externalModules: { autoInstall: false },\n\
         logging: { console: { level: 'warn', metrics: false, audit: false } } };\n",
    )
    .expect("settings");
    std::os::unix::fs::symlink(&modules, user_dir.join("node_modules")).expect("the nodes");
    let red = modules.join("node-red/red.js");
    let log = std::fs::File::create(dir.path().join("node-red.log")).expect("log");
    let started = Instant::now();
    let node_red = std::process::Command::new("node")
        .arg(&red)
        .args(["--userDir", user_dir.to_str().expect("utf-8")])
        .args(["--settings", user_dir.join("settings.js").to_str().expect("utf-8")])
        .stdout(log.try_clone().expect("log"))
        .stderr(log)
        .spawn()
        .expect("Node-RED starts");
    let mut node_red = common::KillOnDrop(node_red);
    let mut got = lines(&out);
    while !complete(&got) && started.elapsed() < Duration::from_secs(90) {
        std::thread::sleep(Duration::from_millis(250));
        got = lines(&out);
    }
    let took = started.elapsed();
    let _ = node_red.kill();
    let _ = node_red.wait();
    let node_red_log = std::fs::read_to_string(dir.path().join("node-red.log")).unwrap_or_default();
    let errors = errors(&got);
    assert!(
        complete(&got),
        "after {took:?}: {} results, errors {errors:?}\nNode-RED:\n{node_red_log}\nPLC:\n{}",
        got.len(),
        plc.log()
    );
    assert!(errors.is_empty(), "errors: {errors:?}\nNode-RED:\n{node_red_log}");
    let log = plc.log();
    assert!(log.contains("t=") && log.contains(": ERROR"), "{log}");
    assert!(!log.contains("refused a connection"), "{log}");
    eprintln!(
        "node-red: 20 OPC UA nodes from one host answered within {:.1} s of Node-RED's start ({} results)",
        took.as_secs_f64(),
        got.len()
    );
}
