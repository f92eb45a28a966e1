// The operator's screen: one WebSocket, frames pushed by the soft-PLC at its main cycle's rate,
// commands sent back. The jog is a dead-man: released on pointer up, when the tab is hidden,
// when the connection drops; while held it is refreshed every 20 ms (the server stops a jog not
// refreshed for 60 ms).
"use strict";

const $ = (id) => document.getElementById(id);
const token = new URLSearchParams(location.search).get("token");
let ws = null;
let variables = [];
// May this page command (it has the token, or none is needed)?
let commands = false;
// The shown program's text is fetched a window at a time: its first line's number, its lines,
// and how many the program has.
let textWindow = { program: 0, from: 1, lines: [], total: 0 };
let textAsked = 0; // the first line of the window last asked for (0: none pending)
let jog = null; // [x, y, axis] while held
// The run's programs (numbered from 1 as NC_PROGRAM holds the loaded one's) and the one shown.
let programs = [];
let shownProgram = 0;
// The screen makes jobs (MDI, a program from a line).
let jobs = false;
// The programs offered that cannot run on this machine, with why.
let refused = [];
let jogTimer = null;
let lastLine = 0;
// The tool path: programmed (from the server), cut (the measured tool point x y z while a
// program runs: what the server kept of the run before this page saw it, then every frame).
let programmed = [];
let cut = [];
let cutAsked = false;
let plane = [0, 1];
let index = {};
// The mechanism's views: the planes of its largest extents, each with a frame that grows to
// everything drawn so far (so that it does not jump).
let views = null;
// The tool table's tools: number → comment (the tool change names them).
let tools = {};
// The last message (MSG) shown: its time, so that a new one replaces it.
let shownMessage = null;
// The update latency: from the cycle's publication to this page (ms), the last 2000 frames.
window.latency = [];

function send(command) {
  if (ws && ws.readyState === WebSocket.OPEN) {
    ws.send(JSON.stringify(command));
  }
}

function connect() {
  const url = new URL("ws", location.href);
  url.protocol = location.protocol === "https:" ? "wss:" : "ws:";
  if (token) url.searchParams.set("token", token);
  ws = new WebSocket(url);
  ws.onopen = () => { $("link").textContent = "connected"; $("link").className = "good"; };
  ws.onclose = () => {
    $("link").textContent = "disconnected: reconnecting…";
    $("link").className = "bad";
    stopJog();
    setTimeout(connect, 1000);
  };
  ws.onmessage = (e) => {
    const m = JSON.parse(e.data);
    if (m.type === "hello") hello(m);
    else if (m.type === "frame") frame(m);
    else if (m.type === "text") text(m);
    else if (m.type === "path") path(m);
    else if (m.type === "job") job(m);
    else if (m.type === "touch_off") touchedOff(m);
    else if (m.type === "planning") planning(true);
    else if (m.type === "cut" && m.program === shownProgram) cut = m.points;
    else if (m.type === "refused") {
      if (m.job) planning(false);
      $("access").textContent = m.why;
    }
  };
}

function hello(m) {
  index = {};
  m.variables.forEach(([n], i) => { index[n] = i; });
  programs = m.programs || [];
  jobs = !!m.jobs;
  tools = {};
  (m.tools || []).forEach(([n, comment]) => { tools[n] = comment; });
  cutAsked = false;
  $("mdi-box").hidden = !jobs;
  $("from-line-box").hidden = !jobs;
  shownProgram = 0;
  $("program-choice").innerHTML = programs.map((p, i) => `<option value="${i + 1}">${escape(p.file)}</option>`).join("");
  // The choice of programs, where there is one to make (or one to go back to after a job).
  $("library").hidden = programs.length < 2 && !(m.jobs && programs.length);
  // Each reason starts with its file's name.
  refused = m.refused || [];
  $("refused").innerHTML = refused.map((r) => `<div>not offered: ${escape(r.why.split("\n")[0])}</div>`).join("") +
    (m.refused_more ? `<div>… and ${m.refused_more} more (see the log)</div>` : "");
  showProgram(programs.length ? 1 : 0);
  // A pair of press-and-hold buttons per pose coordinate of the machine (axis k), and per joint
  // (axis −k: the joint alone, once referenced).
  const pair = (label, axis, title) =>
    `<button class="jog-btn" data-axis="${axis}" data-x="-1" title="${title}">− ${label}</button>` +
    `<button class="jog-btn" data-axis="${axis}" data-x="1" title="${title}">+ ${label}</button>`;
  $("jog-buttons").innerHTML = (m.axes || []).map((a, k) => pair(a, k + 1, `the tool along ${a}`)).join("");
  $("joint-buttons").innerHTML = (m.joints || []).map((v, k) => pair(`q${k + 1}`, -(k + 1), `joint ${k + 1} alone (${v})`)).join("");
  $("joint-hint").hidden = !(m.joints || []).length;
  $("touch-axis").innerHTML = (m.axes || []).map((a) => `<option value="${a}">${a.toUpperCase()}</option>`).join("");
  $("touch-off-box").hidden = !m.jobs || !(m.axes || []).length;
  for (const b of document.querySelectorAll(".jog-btn")) {
    b.addEventListener("pointerdown", (e) => {
      b.setPointerCapture(e.pointerId);
      b.classList.add("held");
      startJog(Number(b.dataset.x), 0, Number(b.dataset.axis));
    });
    for (const end of ["pointerup", "pointercancel", "lostpointercapture"]) b.addEventListener(end, stopJog);
  }
  $("machine").textContent = m.machine;
  $("config").textContent = m.config;
  variables = m.variables;
  commands = m.commands;
  $("access").textContent = commands ? "" : "watching only: commands need the token (?token=…)";
  document.body.dataset.commands = commands;
  // A watching page shows what it cannot do: its controls disabled.
  enableControls(commands);
  // The token has done its work (the server keeps it in an HttpOnly cookie for this page's
  // reconnections): it leaves the address bar and the history.
  if (token && commands && history.replaceState) history.replaceState(null, "", location.pathname);
  const watch = $("watch");
  watch.innerHTML = "<tr><th>variable</th><th>type</th><th>value</th></tr>" +
    variables.map(([n, t], i) => `<tr data-name="${n.toLowerCase()}"><td>${n}</td><td>${t}</td><td class="num" id="v-${i}"></td></tr>`).join("");
  filter();
}

// Shows the run's program number k (from 1; 0: none): its text and path as the server sends
// them, nothing cut yet.
function showProgram(k) {
  shownProgram = k;
  // A job made on the screen (by this page or another): its file and text come from the server.
  if (k > 0 && !programs[k - 1] && jobs) programs[k - 1] = { file: `job ${k}`, lines: 0 };
  const program = programs[k - 1];
  $("program-box").hidden = !program && !refused.length && !jobs;
  programmed = [];
  cut = [];
  lastLine = 0;
  $("path-box").hidden = true;
  textWindow = { program: k, from: 1, lines: [], total: program ? program.lines : 0 };
  $("program-text").innerHTML = "";
  if (!program) return;
  $("program-file").textContent = program.file;
  $("program-choice").value = String(k);
  askText(1);
  send({ cmd: "path", program: k });
}

// A job this page made: loaded and started by the server; shown once the PLC has loaded it.
// A job of this screen is being planned (its Cancel shown), or no longer.
function planning(on) {
  $("nc-cancel").hidden = !on;
  if (on) $("access").textContent = "planning the job …";
}

function job(m) {
  planning(false);
  programs[m.program - 1] = { file: m.file, lines: m.lines };
  $("access").textContent = `${m.file}: planned ${m.planned_s.toFixed(2)} s, ${m.started ? "started" : "loaded"}`;
}

// A touch-off made: the system's origin before and after; the loaded program planned again.
function touchedOff(m) {
  planning(false);
  let said = `${m.system} ${m.axis.toUpperCase()} = ${m.value}: origin ${m.was.toFixed(3)} → ${m.now.toFixed(3)} mm`;
  if (m.job && m.job.type === "job") {
    programs[m.job.program - 1] = { file: m.job.file, lines: m.job.lines };
    said += `; ${m.job.file} planned again and loaded`;
  } else if (m.job) {
    said += `; the loaded program could not be planned again: ${m.job.why}`;
  }
  $("access").textContent = said;
}

// Asks for the window of the shown program's text that starts at line `from`.
function askText(from) {
  if (textAsked === from) return;
  textAsked = from;
  send({ cmd: "text", program: shownProgram, from });
}

function text(m) {
  if (m.program !== shownProgram) return;
  textAsked = 0;
  if (m.file && programs[m.program - 1]) {
    programs[m.program - 1].file = m.file;
    $("program-file").textContent = m.file;
  }
  textWindow = { program: m.program, from: m.from, lines: m.lines, total: m.total };
  $("program-text").innerHTML = m.lines
    .map((l, i) => `<div class="line" id="line-${m.from + i}">${String(m.from + i).padStart(4)}  ${escape(l)}</div>`)
    .join("") + (m.from + m.lines.length <= m.total ? `<div class="line">      … ${m.total} lines</div>` : "");
  const now = document.getElementById("line-" + lastLine);
  if (now) now.classList.add("current");
}

// The programmed path of the shown program, in the plane of its two largest extents (of x y z).
function path(m) {
  if (m.program !== shownProgram) return;
  programmed = m.path;
  if (programmed.length > 1) {
    const extent = [0, 1, 2].map((c) => Math.max(...programmed.map((p) => p[c])) - Math.min(...programmed.map((p) => p[c])));
    plane = [0, 1, 2].sort((a, b) => extent[b] - extent[a] || a - b).slice(0, 2).sort();
  }
  $("path-box").hidden = programmed.length < 2;
}

// Keeps the executing line in the text's window: a new window around it when it nears an edge
// the program goes beyond.
function followLine(line) {
  const w = textWindow;
  if (!line || !w.lines.length) return;
  const last = w.from + w.lines.length - 1;
  const nearStart = line < w.from + 50 && w.from > 1;
  const nearEnd = line > last - 50 && last < w.total;
  if (line < w.from || line > last || nearStart || nearEnd) askText(Math.max(1, line - 100));
}

// Enables or disables every control: the buttons, the program choice, the jog pad.
function enableControls(on) {
  for (const c of document.querySelectorAll("button, select, .overrides input, #from-line, #mdi-text, #touch-value")) c.disabled = !on;
  $("pad").classList.toggle("disabled", !on);
}

function escape(s) {
  return s.replace(/[&<>]/g, (c) => ({ "&": "&amp;", "<": "&lt;", ">": "&gt;" })[c]);
}

function num(v, digits) {
  return v === null || v === undefined || Number.isNaN(v) ? "–" : Number(v).toFixed(digits);
}

function frame(m) {
  const latency = performance.timeOrigin + performance.now() - m.published_unix_us / 1000;
  window.latency.push(latency);
  if (window.latency.length > 2000) window.latency.shift();
  const sorted = [...window.latency].sort((a, b) => a - b);
  const mean = sorted.reduce((a, b) => a + b, 0) / sorted.length;
  $("latency").textContent = `update ${mean.toFixed(1)} ms mean, ${sorted[Math.floor(sorted.length * 0.99)].toFixed(1)} ms p99`;
  const state = $("state");
  state.textContent = m.state || "—";
  state.className = "state " + (m.state || "");
  $("reason").textContent = m.reason;
  $("note").textContent = m.note;
  document.body.dataset.state = m.state;
  $("values").innerHTML = m.values
    .map(([n, v]) => `<tr><td>${n}</td><td class="num" data-value="${n}">${num(v, n === "line" ? 0 : 3)}</td></tr>`).join("");
  $("classes").innerHTML = "<tr><th>class</th><th>cycles</th><th>late mean / max µs</th><th>exec mean / max µs</th><th>overruns</th></tr>" +
    m.classes.map((c) => `<tr><td>${c.name}</td><td class="num">${c.cycles}</td><td class="num">${num(c.late_mean_us, 1)} / ${num(c.late_max_us, 1)}</td><td class="num">${num(c.exec_mean_us, 1)} / ${num(c.exec_max_us, 1)}</td><td class="num">${c.overruns}</td></tr>`).join("") +
    `<tr><td>bus</td><td colspan="4">${m.bus_fault ? "FAULT" : "ok"}</td></tr>` +
    ("JOYSTICK_CONNECTED" in index
      ? `<tr><td>joystick</td><td colspan="4">${m.image[index.JOYSTICK_CONNECTED] ? "connected" : "not connected"}</td></tr>`
      : "");
  m.image.forEach((v, i) => {
    const cell = document.getElementById("v-" + i);
    if (cell) cell.textContent = typeof v === "number" && !Number.isInteger(v) ? v.toFixed(4) : String(v);
  });
  showOverrides(m);
  showTools(m);
  // The loaded program, as the PLC says (a load takes effect outside AUTO).
  if ("NC_PROGRAM" in index && m.image[index.NC_PROGRAM] !== shownProgram) showProgram(m.image[index.NC_PROGRAM]);
  // What was cut before this page connected (once the loaded program is known).
  if ("NC_PROGRAM" in index && !cutAsked) {
    cutAsked = true;
    send({ cmd: "cut" });
  }
  drawPath(m);
  drawMechanism(m.links);
  const lineIndex = variables.findIndex(([n]) => n === "NC_LINE");
  const line = lineIndex >= 0 ? m.image[lineIndex] : 0;
  if (line !== lastLine) {
    followLine(line);
    const old = document.getElementById("line-" + lastLine);
    if (old) old.classList.remove("current");
    const now = document.getElementById("line-" + line);
    if (now) {
      now.classList.add("current");
      // Scrolls the program's text alone (never the page) to keep the line in view.
      const box = $("program-text"), r = now.getBoundingClientRect(), b = box.getBoundingClientRect();
      if (r.top < b.top || r.bottom > b.bottom) box.scrollTop += r.top - b.top - b.height / 2;
    }
    lastLine = line;
  }
}

// The manual tool change (the program stands until confirmed), the tool in the spindle, and
// the program's last message (MSG).
function showTools(m) {
  const value = (name) => (name in index ? m.image[index[name]] : null);
  const asked = value("TOOL_PREP_NUMBER");
  const waits = value("TOOL_CHANGE") === true;
  $("tool-change").hidden = !waits;
  if (waits) {
    const name = tools[asked] ? ` (${tools[asked]})` : "";
    $("tool-ask").textContent = asked === 0
      ? "Tool change: take the tool out of the spindle, then confirm."
      : `Tool change: put tool ${asked}${name} in the spindle, then confirm.`;
  }
  const inSpindle = value("TOOL_NUMBER");
  $("tool-in").textContent = inSpindle ? `tool ${inSpindle}${tools[inSpindle] ? " (" + tools[inSpindle] + ")" : ""} in the spindle` : "";
  if (m.message && (!shownMessage || shownMessage[0] !== m.message[0] || shownMessage[2] !== m.message[2])) {
    shownMessage = m.message;
    const [t, line, text] = m.message;
    $("message").hidden = false;
    $("message").textContent = `message, line ${line} (t = ${t.toFixed(1)} s): ${text}`;
  }
}

// The overrides and single block as the PLC has them (a slider being dragged shows its own).
function showOverrides(m) {
  for (const [name, id] of [["NC_FEED_OVERRIDE", "feed"], ["NC_RAPID_OVERRIDE", "rapid"]]) {
    if (!(name in index)) continue;
    const v = m.image[index[name]];
    const slider = $(id + "-override");
    if (document.activeElement !== slider) slider.value = v;
    $(id + "-value").textContent = `${v} %`;
  }
  if ("NC_SINGLE_BLOCK" in index) $("single-block").checked = m.image[index.NC_SINGLE_BLOCK];
}

function drawPath(m) {
  if (programmed.length < 2) return;
  const value = (name) => (name in index ? m.image[index[name]] : null);
  const tool = ["NC_TOOL_X", "NC_TOOL_Y", "NC_TOOL_Z"].map(value);
  // Running, holding, held, paused at an M0, standing after a line in single block, at a tool
  // change.
  const running = [1, 2, 3, 4, 6, 7].includes(value("NC_STATE"));
  if (running && tool[0] !== null && tool[1] !== null) {
    cut.push(tool.map((v) => v ?? 0));
    if (cut.length > 20000) cut.shift();
  }
  const canvas = $("path");
  const g = canvas.getContext("2d");
  const pts = programmed.map((p) => [p[plane[0]], p[plane[1]]]);
  const xs = pts.map((p) => p[0]), ys = pts.map((p) => p[1]);
  const [x0, x1, y0, y1] = [Math.min(...xs), Math.max(...xs), Math.min(...ys), Math.max(...ys)];
  const span = Math.max(x1 - x0, y1 - y0, 1e-3) * 1.1;
  const [cx, cy] = [(x0 + x1) / 2, (y0 + y1) / 2];
  const px = (p) => [(p[0] - cx) / span * canvas.width + canvas.width / 2, canvas.height / 2 - (p[1] - cy) / span * canvas.height];
  g.clearRect(0, 0, canvas.width, canvas.height);
  const line = (points, style, width) => {
    g.strokeStyle = style; g.lineWidth = width; g.beginPath();
    points.forEach((p, i) => { const [x, y] = px(p); if (i === 0) g.moveTo(x, y); else g.lineTo(x, y); });
    g.stroke();
  };
  line(pts, "#bbb", 3);
  const cutIn = cut.map((p) => [p[plane[0]], p[plane[1]]]);
  line(cutIn, "#06c", 1.5);
  const at = cutIn[cutIn.length - 1];
  if (at) { const [x, y] = px(at); g.fillStyle = "#c00"; g.beginPath(); g.arc(x, y, 4, 0, 2 * Math.PI); g.fill(); }
}

function drawMechanism(links) {
  if (!links) return;
  $("mechanism-box").hidden = false;
  if (!views) {
    // The two largest extents (of x y z) make the first view; a third that matters, a second.
    const points = links.flat();
    const size = [0, 1, 2].map((c) => Math.max(...points.map((p) => p[c])) - Math.min(...points.map((p) => p[c])));
    const order = [0, 1, 2].sort((a, b) => size[b] - size[a] || a - b);
    views = [[order[0], order[1]].sort()];
    if (size[order[2]] > 0.1 * size[order[0]]) views.push([order[0], order[2]].sort());
    views = views.map((axes) => ({ axes, extent: null }));
    $("mechanism2").hidden = views.length < 2;
    $("views").textContent = views.map((v) => v.axes.map((c) => "xyz"[c]).join("–")).join(", ");
  }
  views.forEach((view, i) => drawView(i === 0 ? "mechanism" : "mechanism2", view, links));
}

function drawView(id, view, links) {
  const [u, v] = view.axes;
  const flat = links.map(([a, b]) => [[a[u], a[v]], [b[u], b[v]]]);
  for (const [a, b] of flat) {
    for (const p of [a, b]) {
      const e = view.extent || [p[0], p[0], p[1], p[1]];
      view.extent = [Math.min(e[0], p[0]), Math.max(e[1], p[0]), Math.min(e[2], p[1]), Math.max(e[3], p[1])];
    }
  }
  const extent = view.extent;
  const canvas = $(id);
  const g = canvas.getContext("2d");
  const span = Math.max(extent[1] - extent[0], extent[3] - extent[2], 1e-3) * 1.1;
  const [cx, cy] = [(extent[0] + extent[1]) / 2, (extent[2] + extent[3]) / 2];
  const px = (p) => [(p[0] - cx) / span * canvas.width + canvas.width / 2, canvas.height / 2 - (p[1] - cy) / span * canvas.height];
  g.clearRect(0, 0, canvas.width, canvas.height);
  g.strokeStyle = "#333";
  g.lineWidth = 3;
  for (const [a, b] of flat) {
    const [x0, y0] = px(a), [x1, y1] = px(b);
    g.beginPath(); g.moveTo(x0, y0); g.lineTo(x1, y1); g.stroke();
    g.fillStyle = "#06c";
    for (const [x, y] of [[x0, y0], [x1, y1]]) { g.beginPath(); g.arc(x, y, 4, 0, 2 * Math.PI); g.fill(); }
  }
}

function filter() {
  const f = $("filter").value.toLowerCase();
  for (const row of $("watch").querySelectorAll("tr[data-name]")) {
    row.hidden = f !== "" && !row.dataset.name.includes(f);
  }
}

function startJog(x, y, axis = 0) {
  if (!commands) return;
  jog = [x, y, axis];
  send({ cmd: "jog", x, y, axis });
  if (!jogTimer) jogTimer = setInterval(() => { if (jog) send({ cmd: "jog", x: jog[0], y: jog[1], axis: jog[2] }); }, 20);
}

function stopJog() {
  if (jogTimer) { clearInterval(jogTimer); jogTimer = null; }
  if (jog) { jog = null; send({ cmd: "jog", x: 0, y: 0 }); }
  for (const b of document.querySelectorAll(".jog-btn.held")) b.classList.remove("held");
  $("pad-dot").style.left = "72px";
  $("pad-dot").style.top = "72px";
}


const pad = $("pad");
function padAt(e) {
  const r = pad.getBoundingClientRect();
  let x = (e.clientX - r.left) / r.width * 2 - 1;
  let y = 1 - (e.clientY - r.top) / r.height * 2;
  const len = Math.hypot(x, y);
  if (len > 1) { x /= len; y /= len; }
  $("pad-dot").style.left = `${72 + x * 72}px`;
  $("pad-dot").style.top = `${72 - y * 72}px`;
  startJog(x, y);
}
// Until the server says this page may command (its hello), the controls are disabled.
enableControls(false);
pad.addEventListener("pointerdown", (e) => { pad.setPointerCapture(e.pointerId); padAt(e); });
pad.addEventListener("pointermove", (e) => { if (jog && pad.hasPointerCapture(e.pointerId)) padAt(e); });
for (const end of ["pointerup", "pointercancel", "lostpointercapture"]) pad.addEventListener(end, stopJog);

document.addEventListener("visibilitychange", () => { if (document.hidden) stopJog(); });
window.addEventListener("blur", stopJog);

$("stop").addEventListener("click", () => send({ cmd: "stop" }));
$("ack").addEventListener("click", () => send({ cmd: "acknowledge" }));
$("axes").addEventListener("click", () => send({ cmd: "axes" }));
$("nc-load").addEventListener("click", () => { $("access").textContent = ""; send({ cmd: "load", program: Number($("program-choice").value) }); });
$("nc-start").addEventListener("click", () => send({ cmd: "program", what: "start" }));
$("nc-hold").addEventListener("click", () => send({ cmd: "program", what: "hold" }));
$("nc-resume").addEventListener("click", () => send({ cmd: "program", what: "resume" }));
$("tool-changed").addEventListener("click", () => send({ cmd: "tool_changed" }));
$("touch-off").addEventListener("click", () => {
  send({ cmd: "touch_off", system: Number($("touch-system").value), axis: $("touch-axis").value, value: Number($("touch-value").value) });
});
for (const id of ["feed", "rapid"]) {
  $(id + "-override").addEventListener("input", (e) => {
    $(id + "-value").textContent = `${e.target.value} %`;
    send({ cmd: "override", [id]: Number(e.target.value) });
  });
}
$("single-block").addEventListener("change", (e) => send({ cmd: "single_block", on: e.target.checked }));
$("nc-mdi").addEventListener("click", () => {
  $("access").textContent = "";
  send({ cmd: "mdi", text: $("mdi-text").value });
});
$("nc-cancel").addEventListener("click", () => send({ cmd: "cancel" }));
$("nc-from-line").addEventListener("click", () => {
  $("access").textContent = "";
  send({ cmd: "run_from", program: shownProgram, line: Number($("from-line").value) });
});
$("program-text").addEventListener("click", (e) => {
  const line = e.target.closest(".line");
  if (line && line.id.startsWith("line-")) $("from-line").value = line.id.slice(5);
});
$("filter").addEventListener("input", filter);

connect();
