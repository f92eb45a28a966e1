// The operator's screen: one WebSocket, frames pushed by the soft-PLC at its main cycle's rate,
// commands sent back. The jog is a dead-man: released on pointer up, when the tab is hidden,
// when the connection drops; while held it is refreshed every 20 ms (the server stops a jog not
// refreshed for 60 ms).
//
// What the page costs the browser is kept small (the page and the PLC often share one PC): it
// asks the server for a few frames a second (each carries the tool's recent points, so the cut
// path misses none) and draws each in the animation frame it arrives for, one frame of the
// browser per frame of the server; text is written only where it changed, the process image's
// table only while it is in view (else once a second), the task classes' table once a second,
// and the drawings only where a pixel would change.
"use strict";

const $ = (id) => document.getElementById(id);
const query = new URLSearchParams(location.search);
// How often the page is drawn (Hz): every frame a software-rendering browser composes costs it
// a few ms of CPU however little changed, so the page asks for 4 frames a second. A browser with
// a GPU can ask for more with `?hz=` (1 … 20).
const DISPLAY_HZ = Number(query.get("hz")) || 4;
const token = query.get("token");
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
// The tool path: programmed (from the server: x y z and whether the way there is a rapid), cut
// (the measured tool point x y z while a program runs: what the server kept of the run before
// this page saw it, then every frame).
let programmed = [];
let cut = [];
let cutAsked = false;
let plane = [0, 1];
let index = {};
// The machine's pose coordinates (x, y, …) and the work systems' origins (G54 first).
let axes = [];
let origins = null;
// The mechanism's views: the planes of its largest extents, each with a frame that grows to
// everything drawn so far (so that it does not jump); the last links drawn.
let views = null;
let links = null;
// The mechanism at mid-travel (from the hello): with the programmed path, the 3-D scene's extent,
// so that path and machine are drawn at one scale, the machine's, whatever its pose.
let mechanismSample = null;
// The 3-D view of the path (and the mechanism): its turn, tilt and zoom, and a drag under way.
const view3d = { on: false, yaw: -0.6, pitch: 0.9, zoom: 1, drag: null };
// The tool table's tools: number → comment (the tool change names them).
let tools = {};
// The last message (MSG) shown: its time, so that a new one replaces it.
let shownMessage = null;
// What each element shows now (written only when it changes).
const shown = new Map();
let watchVisible = false;
let watchAt = 0;
let classesAt = 0;
let drawPending = false;
// What the path's layers show: the programmed path (drawn again only when the program or the
// view changes) and how much of the cut path is drawn (only the newest segments are added).
let pathDrawn = false;
let cutMoved = false;
let cutDrawn = 0;
// The pixel coordinates of the tool's layer as last drawn (null: to be drawn).
let toolDrawn = null;
// The update latency: from the cycle's publication to this page (ms), the last 2000 frames.
window.latency = [];
let latencyAt = 0;

function send(command) {
  if (ws && ws.readyState === WebSocket.OPEN) {
    ws.send(JSON.stringify(command));
  }
}

// Sets an element's text (or a cell's) only where it changed.
function put(element, text) {
  if (!element || shown.get(element) === text) return;
  shown.set(element, text);
  element.textContent = text;
}

function connect() {
  const url = new URL("ws", location.href);
  url.protocol = location.protocol === "https:" ? "wss:" : "ws:";
  if (token) url.searchParams.set("token", token);
  ws = new WebSocket(url);
  ws.onopen = () => {
    $("link").textContent = "connected";
    $("link").className = "good";
    send({ cmd: "frames", hz: DISPLAY_HZ });
  };
  ws.onclose = () => {
    $("link").textContent = "disconnected: reconnecting…";
    $("link").className = "bad";
    stopJog();
    setTimeout(connect, 1000);
  };
  ws.onmessage = (e) => {
    const m = JSON.parse(e.data);
    if (m.type === "hello") hello(m);
    else if (m.type === "frame") take(m);
    else if (m.type === "text") text(m);
    else if (m.type === "path") path(m);
    else if (m.type === "job") job(m);
    else if (m.type === "touch_off") touchedOff(m);
    else if (m.type === "tools") showToolTable(m);
    else if (m.type === "tool") toolKept(m);
    else if (m.type === "origins") { origins = m.origins; }
    else if (m.type === "alarm") alarm(m, true);
    else if (m.type === "planning") planning(true);
    else if (m.type === "cut" && m.program === shownProgram) { cut = m.points; redraw(true); }
    else if (m.type === "refused") {
      if (m.job) planning(false);
      $("access").textContent = m.why;
    }
  };
}

function hello(m) {
  index = {};
  shown.clear();
  classRows = "";
  droCells = null;
  m.variables.forEach(([n], i) => { index[n] = i; });
  programs = m.programs || [];
  jobs = !!m.jobs;
  tools = {};
  (m.tools || []).forEach(([n, comment]) => { tools[n] = comment; });
  axes = m.axes || [];
  origins = m.origins || null;
  showToolTable(m.tool_table || null);
  layOutMechanism(m.mechanism_sample || null);
  mechanismSample = m.mechanism_sample || null;
  cutAsked = false;
  trailSeq = 0;
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
  // The DRO: per pose coordinate its work and machine position (large), per joint its position
  // and whether it is referenced.
  $("dro").innerHTML = "<tr><th></th><th>work <span id=\"dro-system\">G54</span></th><th>machine</th></tr>" +
    axes.map((a) => `<tr data-axis="${a}"><th class="big">${a.toUpperCase()}</th><td class="num big" id="work-${a}">–</td><td class="num" data-value="${a}">–</td></tr>`).join("");
  $("joints").innerHTML = (m.joints || []).map((v, k) =>
    `<span class="joint" title="${escape(v)}"><span id="homed-${k + 1}">○</span> q${k + 1} <span class="num" data-value="q${k + 1}">–</span></span>`).join(" ");
  // A pair of press-and-hold buttons per pose coordinate of the machine (axis k), and per joint
  // (axis −k: the joint alone, once referenced).
  const pair = (label, axis, title) =>
    `<button class="jog-btn" data-axis="${axis}" data-x="-1" title="${title}">− ${label}</button>` +
    `<button class="jog-btn" data-axis="${axis}" data-x="1" title="${title}">+ ${label}</button>`;
  $("jog-buttons").innerHTML = axes.map((a, k) => pair(a, k + 1, `the tool along ${a}`)).join("");
  $("joint-buttons").innerHTML = (m.joints || []).map((v, k) => pair(`q${k + 1}`, -(k + 1), `joint ${k + 1} alone (${v})`)).join("");
  $("joint-hint").hidden = !(m.joints || []).length;
  for (const b of document.querySelectorAll(".jog-btn")) {
    b.addEventListener("pointerdown", (e) => {
      const axis = Number(b.dataset.axis), step = Number($("jog-step").value);
      // A step per click along a pose coordinate; a joint jogs while held.
      if (step > 0 && axis > 0) {
        send({ cmd: "step", axis: axes[axis - 1], mm: step * Number(b.dataset.x) });
        return;
      }
      b.setPointerCapture(e.pointerId);
      b.classList.add("held");
      startJog(Number(b.dataset.x), 0, axis);
    });
    for (const end of ["pointerup", "pointercancel", "lostpointercapture"]) b.addEventListener(end, stopJog);
  }
  $("touch-axis").innerHTML = axes.map((a) => `<option value="${a}">${a.toUpperCase()}</option>`).join("");
  $("touch-off-box").hidden = !m.jobs || !axes.length;
  $("view3d-switch").hidden = axes.length < 3;
  $("machine").textContent = m.machine;
  // A paced simulation says so, always in view: a student checks a program on it before the
  // machine runs it.
  $("simulation").hidden = !m.simulation;
  $("simulation").textContent = m.simulation ? `simulation at ${m.simulation}× real time` : "";
  $("config").textContent = m.config;
  variables = m.variables;
  commands = m.commands;
  $("access").textContent = commands ? "" : "watching only: commands need the token (?token=…)";
  document.body.dataset.commands = commands;
  // A watching page shows what it cannot do: its controls disabled.
  enableControls(commands);
  // The token has done its work (the server keeps it in an HttpOnly cookie for this page's
  // reconnections): it leaves the address bar and the history.
  if (token && commands && history.replaceState) {
    const kept = new URLSearchParams(location.search);
    kept.delete("token");
    history.replaceState(null, "", location.pathname + (kept.size ? `?${kept}` : ""));
  }
  const watch = $("watch");
  watch.innerHTML = "<tr><th>variable</th><th>type</th><th>value</th></tr>" +
    variables.map(([n, t], i) => `<tr data-name="${n.toLowerCase()}"><td>${n}</td><td>${t}</td><td class="num" id="v-${i}"></td></tr>`).join("");
  filter();
  $("alarms").innerHTML = "<tr><th>time</th><th>what</th><th></th></tr>";
  (m.alarms || []).forEach((a) => alarm(a, false));
}

// An entry of the alarm and message history, newest first.
function alarm(a, fresh) {
  const row = document.createElement("tr");
  row.className = "alarm " + a.kind.replace(/ /g, "-");
  const at = new Date(a.unix_ms).toLocaleTimeString();
  row.innerHTML = `<td class="num" title="t = ${a.t_s.toFixed(2)} s">${at}</td><td>${escape(a.kind)}</td><td>${escape(a.text)}${a.by ? ` <span class="hint">by ${escape(a.by)}</span>` : ""}</td>`;
  const header = $("alarms").firstChild;
  header.after(row);
  while ($("alarms").rows.length > 201) $("alarms").deleteRow(-1);
  if (fresh && a.kind === "error") row.classList.add("fresh");
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
  chooseShown(k, program.file);
  askText(1);
  send({ cmd: "path", program: k });
}

// The program chooser on program k: a job of the screen (a run from a line, MDI) gets an
// option of its own, named as its file, in place of the last job's — the chooser never shows
// blank while a job is loaded.
function chooseShown(k, file) {
  const choice = $("program-choice");
  for (const o of [...choice.options]) if (o.dataset.job && o.value !== String(k)) o.remove();
  if (![...choice.options].some((o) => o.value === String(k))) {
    const o = document.createElement("option");
    o.value = String(k);
    o.dataset.job = "1";
    o.textContent = file;
    choice.append(o);
  }
  choice.value = String(k);
}

// A job this page made: loaded and started by the server; shown once the PLC has loaded it.
// A job of this screen is being planned (its Cancel shown), or no longer.
function planning(on) {
  $("nc-cancel").hidden = !on;
  if (on) $("access").textContent = "planning the job …";
}

function job(m) {
  planning(false);
  programs[m.program - 1] = { file: m.file, lines: m.lines, planned_s: m.planned_s };
  $("access").textContent = `${m.file}: planned ${m.planned_s.toFixed(2)} s, ${m.started ? "started" : "loaded"}`;
}

// The tool table (from the hello, and after every change, whoever made it): a row per tool
// with its pocket, the offsets of the machine's axes, diameter and comment, each row saved or
// removed on its own. Offsets of axes the machine has not are kept as they are.
let toolTable = null;
const POSE = ["x", "y", "z", "a", "b", "c"];

function showToolTable(t) {
  toolTable = t;
  $("tools-box").hidden = !t;
  if (!t) return;
  tools = {};
  t.tools.forEach((tool) => { tools[tool.number] = tool.comment; });
  $("tools-file").textContent = t.writes ? t.file : `${t.file} — a simulation: changes are kept for this run only`;
  const shown = POSE.map((a, c) => [a, c]).filter(([a]) => axes.includes(a));
  $("tools").tHead.innerHTML = `<tr><th>T</th><th>P</th>${shown.map(([a]) => `<th>${a.toUpperCase()}</th>`).join("")}<th>D</th><th>comment</th><th></th></tr>`;
  const field = (cls, value, extra = "") => `<input class="${cls}" type="number" step="any" value="${value}" ${extra}>`;
  $("tools").tBodies[0].innerHTML = t.tools.map((tool) => `<tr data-tool="${tool.number}"><td>T${tool.number}</td>`
    + `<td>${field("pocket", tool.pocket, 'min="0" step="1"')}</td>`
    + shown.map(([, c]) => `<td>${field("offset", tool.offsets[c], `data-c="${c}"`)}</td>`).join("")
    + `<td>${field("diameter", tool.diameter, 'min="0"')}</td>`
    + `<td><input class="comment" maxlength="120" value="${escape(tool.comment)}"></td>`
    + `<td><button class="tool-save">Save</button> <button class="tool-remove">Remove</button></td></tr>`).join("");
  enableControls(commands);
}

// Sends a row of the tool table as the operator left it.
function saveTool(row) {
  const number = Number(row.dataset.tool);
  const tool = toolTable.tools.find((t) => t.number === number);
  const offsets = tool ? [...tool.offsets] : [0, 0, 0, 0, 0, 0];
  for (const input of row.querySelectorAll(".offset")) offsets[Number(input.dataset.c)] = Number(input.value);
  send({
    cmd: "tool", number, pocket: Number(row.querySelector(".pocket").value), offsets,
    diameter: Number(row.querySelector(".diameter").value), comment: row.querySelector(".comment").value,
  });
}

function toolKept(m) {
  $("tools-status").textContent = `${m.what}: ${m.written ? "written to the file" : "kept for this simulation"}`;
  if (m.job) $("access").textContent = m.job.type === "refused" ? m.job.why : `${m.job.file}: planned again with the tool table, loaded`;
}

// A touch-off made: the system's origin before and after; the loaded program planned again.
function touchedOff(m) {
  planning(false);
  let said = `${m.system} ${m.axis.toUpperCase()} = ${m.value}: origin ${num(m.was, 3)} → ${num(m.now, 3)} mm`;
  // Without a parameter file the next start would lose it without a word.
  if (m.kept === false) said += ", kept until the PLC stops only: no parameter file (--var-file, nc.var_file)";
  if (m.job && m.job.type === "job") {
    programs[m.job.program - 1] = { file: m.job.file, lines: m.job.lines, planned_s: m.job.planned_s };
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
    const option = [...$("program-choice").options].find((o) => o.dataset.job && o.value === String(m.program));
    if (option) option.textContent = m.file;
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
    const extent = [0, 1, 2].map((c) => extentOf(programmed, c));
    plane = [0, 1, 2].sort((a, b) => extent[b][1] - extent[b][0] - (extent[a][1] - extent[a][0]) || a - b).slice(0, 2).sort();
  }
  $("path-box").hidden = programmed.length < 2;
  redraw(true);
}

// The smallest and largest coordinate c of `points` (without spreading a large array).
function extentOf(points, c) {
  let lo = Infinity, hi = -Infinity;
  for (const p of points) { if (p[c] < lo) lo = p[c]; if (p[c] > hi) hi = p[c]; }
  return [lo, hi];
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
  for (const c of document.querySelectorAll("button, select, .overrides input, #from-line, #mdi-text, #touch-value, #tools input, #tool-new")) c.disabled = !on;
  $("pad").classList.toggle("disabled", !on);
}

function escape(s) {
  return s.replace(/[&<>]/g, (c) => ({ "&": "&amp;", "<": "&lt;", ">": "&gt;" })[c]);
}

// A number with `digits` decimals; "–" for none; never "-0.000" (a value that rounds to zero
// has no sign).
function num(v, digits) {
  if (v === null || v === undefined || Number.isNaN(v)) return "–";
  const text = Number(v).toFixed(digits);
  return /^-0(\.0*)?$/.test(text) ? text.slice(1) : text;
}

// A frame as it comes: its latency and the tool's points; drawn at the next animation frame
// (once, however many came).
let newest = null;
let trailSeq = 0;
function take(m) {
  window.latency.push(performance.timeOrigin + performance.now() - m.published_unix_us / 1000);
  if (window.latency.length > 2000) window.latency.shift();
  takeCut(m.trail || []);
  const drawing = newest !== null;
  newest = m;
  if (!drawing) requestAnimationFrame(() => { const f = newest; newest = null; if (f) frame(f); });
}

function frame(m) {
  const now = performance.now();
  if (now - latencyAt > 1000) {
    latencyAt = now;
    const sorted = [...window.latency].sort((a, b) => a - b);
    const mean = sorted.reduce((a, b) => a + b, 0) / sorted.length;
    put($("latency"), `update ${mean.toFixed(1)} ms mean, ${sorted[Math.floor(sorted.length * 0.99)].toFixed(1)} ms p99`);
  }
  const value = (name) => (name in index ? m.image[index[name]] : null);
  const state = $("state");
  put(state, m.state || "—");
  state.className = "state " + (m.state || "");
  put($("reason"), m.reason);
  // At a tool change the prompt below says which tool and what to do (the PLC's note names its
  // signals, for the log and OPC UA clients).
  const toolWaits = "TOOL_CHANGE" in index && m.image[index.TOOL_CHANGE] === true;
  put($("note"), toolWaits ? "" : m.note || (m.state === "ERROR" ? "Press Acknowledge (STOP released) to leave ERROR." : ""));
  if (m.state !== lastState) changedState(lastState, m);
  document.body.dataset.state = m.state;
  showPositions(m, value);
  if (now - classesAt > 1000) {
    classesAt = now;
    showClasses(m);
  }
  // Every frame while in view, once a second out of it (a search of the page finds it current).
  if (watchVisible || now - watchAt > 1000) {
    watchAt = now;
    m.image.forEach((v, i) => {
      put(document.getElementById("v-" + i), typeof v === "number" && !Number.isInteger(v) ? num(v, 4) : String(v));
    });
  }
  showOverrides(m);
  showTools(m);
  showProgress(m, value);
  // The loaded program, as the PLC says (a load takes effect outside AUTO).
  if ("NC_PROGRAM" in index && m.image[index.NC_PROGRAM] !== shownProgram) showProgram(m.image[index.NC_PROGRAM]);
  // What was cut before this page connected (once the loaded program is known).
  if ("NC_PROGRAM" in index && !cutAsked) {
    cutAsked = true;
    send({ cmd: "cut" });
  }
  // The mechanism in ERROR, and until the machine is referenced again (after an acknowledged
  // fault as at power-on; the server sends no pose meanwhile): the last pose drawn, dimmed, and
  // what to do next.
  const error = m.state === "ERROR";
  const unreferenced = "referenced" in index && m.image[index.referenced] !== true;
  $("mechanism-box").classList.toggle("dimmed", error || unreferenced);
  put($("mechanism-note"), error
    ? "ERROR: the last pose drawn before it. Press Acknowledge, then reference the machine."
    : !unreferenced ? "" : links ? "Not referenced: the last pose drawn before; drawn again once the machine is referenced."
    : "Not referenced: the mechanism is drawn once the machine is referenced.");
  // Drawn in this animation frame, not the next: each frame the browser composes costs a
  // software-rendering one a few ms whatever changed in it.
  const moved = m.links && !sameLinks(m.links, links);
  if (moved) links = m.links;
  if (cutMoved || (moved && view3d.on)) drawPath();
  if (moved) drawMechanism();
  cutMoved = false;
  const line = value("NC_LINE") || 0;
  if (line !== lastLine) {
    followLine(line);
    const old = document.getElementById("line-" + lastLine);
    if (old) old.classList.remove("current");
    const current = document.getElementById("line-" + line);
    if (current) {
      current.classList.add("current");
      // Scrolls the program's text alone (never the page) to keep the line in view.
      const box = $("program-text"), r = current.getBoundingClientRect(), b = box.getBoundingClientRect();
      if (r.top < b.top || r.bottom > b.bottom) box.scrollTop += r.top - b.top - b.height / 2;
    }
    lastLine = line;
  }
}

// The task classes' table, the bus and the joystick: its rows made when the classes change,
// then only the cells that changed written (a table made anew is laid out anew).
let classRows = "";
function showClasses(m) {
  const rows = m.classes.map((c) => c.name).join(" ") + ("JOYSTICK_CONNECTED" in index ? " joystick" : "");
  const table = $("classes");
  if (rows !== classRows) {
    classRows = rows;
    for (const cell of table.querySelectorAll("td[id]")) shown.delete(cell);
    table.innerHTML = "<tr><th>class</th><th>cycles</th><th>late mean / max µs</th><th>exec mean / max µs</th><th>overruns</th></tr>" +
      m.classes.map((c, k) => `<tr><td>${escape(c.name)}</td><td class="num" id="class-${k}-0"></td><td class="num" id="class-${k}-1"></td><td class="num" id="class-${k}-2"></td><td class="num" id="class-${k}-3"></td></tr>`).join("") +
      `<tr><td>bus</td><td colspan="4" id="class-bus"></td></tr>` +
      ("JOYSTICK_CONNECTED" in index ? `<tr><td>joystick</td><td colspan="4" id="class-joystick"></td></tr>` : "");
  }
  m.classes.forEach((c, k) => {
    put($(`class-${k}-0`), String(c.cycles));
    put($(`class-${k}-1`), `${num(c.late_mean_us, 1)} / ${num(c.late_max_us, 1)}`);
    put($(`class-${k}-2`), `${num(c.exec_mean_us, 1)} / ${num(c.exec_max_us, 1)}`);
    put($(`class-${k}-3`), String(c.overruns));
  });
  put($("class-bus"), m.bus_fault ? "FAULT" : "ok");
  if ("JOYSTICK_CONNECTED" in index) put($("class-joystick"), m.image[index.JOYSTICK_CONNECTED] ? "connected" : "not connected");
}

// The DRO: machine positions as the main program shows them (the forward kinematics of the
// measured joints), work positions against the G54 origin, the joints with their referenced
// mark; before referencing every position is marked as not trustworthy. Its cells are looked
// up once per hello, not in every frame.
let droCells = null;
function showPositions(m, value) {
  const values = new Map(m.values);
  const referenced = !("referenced" in index) || value("referenced") === true;
  document.body.classList.toggle("untrusted", !referenced);
  // Its line kept when hidden: the DRO does not move when the machine is referenced.
  $("untrusted-note").style.visibility = referenced ? "hidden" : "";
  if (!droCells) {
    const joints = [...document.querySelectorAll("#joints [data-value]")];
    droCells = {
      machine: axes.map((a) => document.querySelector(`#dro td[data-value="${a}"]`)),
      work: axes.map((a) => $("work-" + a)),
      joints,
      homed: joints.map((_, k) => $(`homed-${k + 1}`)),
    };
  }
  // The work position in the running program's coordinates (its work system, G92 and tool
  // offsets: NC_WORK_*), else against G54 as the parameter file and the touch-offs have it.
  const system = value("NC_WORK_SYSTEM") || 0;
  put($("dro-system"), system > 0 ? `G${53 + system}` : "G54");
  axes.forEach((a, c) => {
    const machine = values.get(a);
    put(droCells.machine[c], num(machine, 3));
    const offset = system > 0 ? value(`NC_WORK_OFFSET_${a.toUpperCase()}`) || 0 : origins ? origins[0][c] : 0;
    const work = machine === undefined || machine === null ? null : machine - offset;
    put(droCells.work[c], num(work, 3));
  });
  droCells.joints.forEach((cell, k) => {
    put(cell, num(values.get(`q${k + 1}`), 3));
    put(droCells.homed[k], referenced ? "✓" : "○");
  });
}

// What the page said for a state that has passed: the program's message belongs to its run (a
// new run, a stop or an ERROR ends it), and what a command answered (a touch-off, a job) makes
// way for the ERROR's reason and what to do.
let lastState = null;
function changedState(was, m) {
  lastState = m.state;
  const runEnds = was === "AUTO" && !(m.state === "READY" && m.image[index.NC_COMPLETED] === true);
  // Hidden; the last one shown stays known, so that only a newer message shows again.
  if (m.state === "AUTO" || m.state === "ERROR" || runEnds) $("message").hidden = true;
  if (m.state === "ERROR") $("access").textContent = "";
}

// Feed, spindle, the distance to go and the program's progress (these two only while a program
// runs: a finished or stopped one leaves nothing to go).
function showProgress(m, value) {
  const feed = value("NC_FEED"), measured = value("NC_FEED_MEASURED");
  put($("feed-line"), feed === null ? "–" : `${num(feed, 0)} commanded, ${num(measured, 0)} measured mm/min`);
  const runs = m.state === "AUTO";
  put($("dtg"), !runs || value("NC_DISTANCE_TO_GO") === null ? "–" : `${num(value("NC_DISTANCE_TO_GO"), 3)} mm`);
  const on = value("SPINDLE_ON"), rpm = value("SPINDLE_RPM");
  put($("spindle-line"), on === null ? "–" : on ? `${value("SPINDLE_REVERSE") ? "CCW" : "CW"} ${num(rpm, 0)} rpm` : "off");
  const program = programs[shownProgram - 1];
  const line = value("NC_LINE"), total = textWindow.total;
  const elapsed = value("NC_RUN_S"), at = value("NC_TIME_S");
  let progress = runs && line ? `line ${line} of ${total}` : "–";
  if (runs && elapsed !== null && line) progress += `, ${num(elapsed, 1)} s`;
  if (runs && program && program.planned_s && at !== null && line) progress += `, ${num(Math.max(0, program.planned_s - at), 1)} s to go`;
  put($("progress-line"), progress);
}

// The manual tool change (the program stands until confirmed), the tool in the spindle, and
// the program's last message (MSG).
let toolAsked = { tool: null, change: null };
function showTools(m) {
  const value = (name) => (name in index ? m.image[index[name]] : null);
  const asked = value("TOOL_PREP_NUMBER");
  const waits = value("TOOL_CHANGE") === true;
  toolAsked = { tool: asked, change: value("TOOL_CHANGE_NUMBER") };
  $("tool-change").hidden = !waits;
  if (waits) {
    const name = tools[asked] ? ` (${tools[asked]})` : "";
    put($("tool-ask"), asked === 0
      ? "Tool change: take the tool out of the spindle, then press Tool changed."
      : `Tool change: put tool ${asked}${name} in the spindle, then press Tool changed.`);
  }
  const inSpindle = value("TOOL_NUMBER");
  put($("tool-in"), inSpindle ? `tool ${inSpindle}${tools[inSpindle] ? " (" + tools[inSpindle] + ")" : ""} in the spindle` : "");
  if (m.message && (!shownMessage || shownMessage[0] !== m.message[0] || shownMessage[2] !== m.message[2])) {
    shownMessage = m.message;
    const [t, line, text] = m.message;
    $("message").hidden = false;
    $("message").textContent = `message, line ${line} (t = ${t.toFixed(1)} s): ${text}`;
  }
}

// The overrides and single block as the PLC has them (a slider being dragged shows its own).
function showOverrides(m) {
  for (const [name, id] of [["NC_FEED_OVERRIDE", "feed"], ["NC_RAPID_OVERRIDE", "rapid"], ["NC_SPINDLE_OVERRIDE", "spindle"]]) {
    if (!(name in index)) continue;
    const v = m.image[index[name]];
    const slider = $(id + "-override");
    if (document.activeElement !== slider && Number(slider.value) !== v) slider.value = v;
    put($(id + "-value"), `${v} %`);
  }
  if ("NC_SINGLE_BLOCK" in index) $("single-block").checked = m.image[index.NC_SINGLE_BLOCK];
}

// The measured tool points of the frames since the last one taken (the server keeps them while
// a program runs: running, holding, held, paused, standing after a line, at a tool change).
function takeCut(trail) {
  for (const [seq, x, y, z] of trail) {
    if (seq <= trailSeq) continue;
    trailSeq = seq;
    if (programmed.length < 2) continue;
    const last = cut[cut.length - 1], p = [x, y, z];
    if (!last || last[0] !== p[0] || last[1] !== p[1] || last[2] !== p[2]) {
      cut.push(p);
      if (cut.length > 20000) {
        cut.shift();
        cutDrawn = Math.max(0, cutDrawn - 1);
      }
      cutMoved = true;
    }
  }
}

// Whether two sets of the mechanism's links are the same (each a pair of 3-D points).
function sameLinks(a, b) {
  if (!b || a.length !== b.length) return false;
  for (let i = 0; i < a.length; i++) {
    for (let e = 0; e < 2; e++) {
      const p = a[i][e], q = b[i][e];
      if (p.length !== q.length) return false;
      for (let c = 0; c < p.length; c++) if (p[c] !== q[c]) return false;
    }
  }
  return true;
}

// Draws what moved at the next animation frame (once, however many frames came); `all`: the
// path's layers from scratch (another program, cut path or view).
function redraw(all = false) {
  if (all) pathDrawn = false;
  if (drawPending) return;
  drawPending = true;
  requestAnimationFrame(() => {
    drawPending = false;
    drawPath();
    drawMechanism();
  });
}

// A projection of 3-D points onto the canvas: the path's plane (2-D), or the 3-D view turned
// and tilted as dragged — a parallel projection of the path and the mechanism in one scene at
// the machine's scale. `px.scale` is pixels per millimetre; `px.direction` projects a direction
// (the axis triad).
function projection(canvas) {
  if (!view3d.on) {
    const c = [0, 1, 2].map((k) => extentOf(programmed.length > 1 ? programmed : (links || []).flat(), k));
    const centre = c.map(([lo, hi]) => (lo + hi) / 2 || 0);
    const [u, v] = plane;
    const span = Math.max(c[u][1] - c[u][0], c[v][1] - c[v][0], 1e-3) * 1.1;
    const px = (p) => [(p[u] - centre[u]) / span * canvas.width + canvas.width / 2, canvas.height / 2 - (p[v] - centre[v]) / span * canvas.height];
    px.scale = canvas.width / span;
    return px;
  }
  // The scene: the programmed path and the mechanism at mid-travel (stable: the view does not
  // jump as the machine moves), its diagonal fitting the canvas whatever the turn.
  const scene = programmed.concat((mechanismSample || links || []).flat());
  const c = [0, 1, 2].map((k) => extentOf(scene, k));
  const centre = c.map(([lo, hi]) => (lo + hi) / 2 || 0);
  const diagonal = Math.hypot(...c.map(([lo, hi]) => hi - lo));
  const span = Math.max(diagonal, 1e-3) * 1.1 / view3d.zoom;
  const [cy, sy, cp, sp] = [Math.cos(view3d.yaw), Math.sin(view3d.yaw), Math.cos(view3d.pitch), Math.sin(view3d.pitch)];
  const turn = ([x, y, z]) => {
    const u = x * cy - y * sy, w = x * sy + y * cy;
    return [u, w * cp + z * sp];
  };
  const px = (p) => {
    const [u, v] = turn([p[0] - centre[0], p[1] - centre[1], p[2] - centre[2]]);
    return [u / span * canvas.width + canvas.width / 2, canvas.height / 2 - v / span * canvas.height];
  };
  px.scale = canvas.width / span;
  px.direction = (d) => { const [u, v] = turn(d); return [u, -v]; };
  return px;
}

// The axis triad (x red, y green, z blue, turned with the view) in the lower left corner, and a
// scale bar of a round length in the lower right: drawn with the programmed path, in 3-D.
function drawFrame(g, px) {
  const { width, height } = g.canvas;
  const origin = [34, height - 34];
  g.lineWidth = 2;
  g.font = "12px sans-serif";
  [["x", "#c00"], ["y", "#080"], ["z", "#00c"]].forEach(([name, colour], k) => {
    const d = [0, 0, 0]; d[k] = 1;
    const [u, v] = px.direction(d);
    const [x, y] = [origin[0] + u * 24, origin[1] + v * 24];
    g.strokeStyle = colour; g.fillStyle = colour;
    g.beginPath(); g.moveTo(...origin); g.lineTo(x, y); g.stroke();
    g.fillText(name, x + u * 6 - 3, y + v * 6 + 4);
  });
  // The largest 1, 2 or 5 × 10^k mm no longer than a fifth of the canvas.
  const most = width / 5 / px.scale;
  const decade = 10 ** Math.floor(Math.log10(most));
  const length = [5, 2, 1].map((f) => f * decade).find((l) => l <= most) || decade;
  const bar = length * px.scale;
  const [x1, y1] = [width - 12, height - 16];
  g.strokeStyle = "#333"; g.fillStyle = "#333";
  g.beginPath(); g.moveTo(x1 - bar, y1 - 4); g.lineTo(x1 - bar, y1); g.lineTo(x1, y1); g.lineTo(x1, y1 - 4); g.stroke();
  g.textAlign = "center";
  g.fillText(`${length >= 1 ? length : length.toPrecision(1)} mm`, x1 - bar / 2, y1 - 6);
  g.textAlign = "start";
}

// The path in three layers: the programmed path, the cut path (segments added as the tool
// goes) and the tool (with the mechanism in 3-D), so that a frame draws a few segments, not the
// whole path.
function drawPath() {
  if (programmed.length < 2) return;
  const canvas = $("path");
  const px = projection(canvas);
  if (!pathDrawn) {
    pathDrawn = true;
    cutDrawn = 0;
    toolDrawn = null;
    drawProgrammed(canvas.getContext("2d"), px);
    $("path-cut").getContext("2d").clearRect(0, 0, canvas.width, canvas.height);
  }
  if (cutDrawn > cut.length) {
    cutDrawn = 0;
    toolDrawn = null;
    $("path-cut").getContext("2d").clearRect(0, 0, canvas.width, canvas.height);
  }
  const c = $("path-cut").getContext("2d");
  // New points less than half a pixel from the last one drawn wait for more (drawing them
  // changes no pixel, yet the browser composes the canvas again).
  const newest = cut.length ? px(cut[cut.length - 1]) : null;
  const drawnTo = cutDrawn ? px(cut[cutDrawn - 1]) : null;
  if (cut.length > cutDrawn && (!drawnTo || Math.hypot(newest[0] - drawnTo[0], newest[1] - drawnTo[1]) >= 0.5)) {
    c.strokeStyle = "#06c"; c.lineWidth = 1.5; c.beginPath();
    const from = Math.max(0, cutDrawn - 1);
    for (let i = from; i < cut.length; i++) { const [x, y] = px(cut[i]); if (i === from) c.moveTo(x, y); else c.lineTo(x, y); }
    c.stroke();
    cutDrawn = cut.length;
  }
  // The tool (and the mechanism in 3-D), drawn again only where a pixel would change.
  const tool = (newest ? newest : []).concat(view3d.on && links ? links.flatMap(([a, b]) => [...px(a), ...px(b)]) : []);
  if (samePixels(tool, toolDrawn)) return;
  toolDrawn = tool;
  const g = $("path-tool").getContext("2d");
  g.clearRect(0, 0, canvas.width, canvas.height);
  if (view3d.on && links) {
    // The mechanism as the measured joints put it: its struts, carriages, platform (and the
    // hexapod's spindle), drawn over the path at the same scale.
    g.strokeStyle = "#333"; g.lineWidth = 2; g.beginPath();
    for (const [a, b] of links) { const [x0, y0] = px(a), [x1, y1] = px(b); g.moveTo(x0, y0); g.lineTo(x1, y1); }
    g.stroke();
  }
  if (newest) { const [x, y] = newest; g.fillStyle = "#c00"; g.beginPath(); g.arc(x, y, 4, 0, 2 * Math.PI); g.fill(); }
}

// Whether two drawings' pixel coordinates (flat lists) differ by less than a third of a pixel.
function samePixels(a, b) {
  if (!b || a.length !== b.length) return false;
  for (let i = 0; i < a.length; i++) if (Math.abs(a[i] - b[i]) >= 1 / 3) return false;
  return true;
}

function drawProgrammed(g, px) {
  const canvas = g.canvas;
  g.clearRect(0, 0, canvas.width, canvas.height);
  if (view3d.on) drawFrame(g, px);
  // The programmed path: feed moves solid, rapids dashed.
  g.strokeStyle = "#aaa"; g.lineWidth = 2;
  let rapid = null;
  for (let i = 1; i < programmed.length; i++) {
    const isRapid = programmed[i][3] === 1;
    if (isRapid !== rapid) {
      if (rapid !== null) g.stroke();
      rapid = isRapid;
      g.setLineDash(rapid ? [6, 5] : []);
      g.beginPath();
      const [x, y] = px(programmed[i - 1]);
      g.moveTo(x, y);
    }
    const [x, y] = px(programmed[i]);
    g.lineTo(x, y);
  }
  g.stroke();
  g.setLineDash([]);
}

// The mechanism's box laid out by `sample` (its links in some pose; none: no drawing): the
// two largest extents (of x y z) make the first view; a third that matters, a second. Done at
// the hello, before any pose comes, so that the box is in place from the start.
function layOutMechanism(sample) {
  views = null;
  $("mechanism-box").hidden = !sample;
  if (!sample) return;
  const points = sample.flat();
  const size = [0, 1, 2].map((c) => { const [lo, hi] = extentOf(points, c); return hi - lo; });
  const order = [0, 1, 2].sort((a, b) => size[b] - size[a] || a - b);
  views = [[order[0], order[1]].sort()];
  if (size[order[2]] > 0.1 * size[order[0]]) views.push([order[0], order[2]].sort());
  views = views.map((axes) => ({ axes, extent: null }));
  $("mechanism2").hidden = views.length < 2;
  $("views").textContent = views.map((v) => v.axes.map((c) => "xyz"[c]).join("–")).join(", ");
}

function drawMechanism() {
  if (!links) return;
  if (!views) layOutMechanism(links);
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
  // Drawn again only where a pixel would change.
  const drawing = flat.flatMap(([a, b]) => [...px(a), ...px(b)]);
  if (samePixels(drawing, view.drawn)) return;
  view.drawn = drawing;
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
  // The continuous jog's speed: a share of the machine's.
  const share = Number($("jog-speed").value) / 100;
  x *= share; y *= share;
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
$("reference").addEventListener("click", () => send({ cmd: "reference" }));
$("axes").addEventListener("click", () => send({ cmd: "axes" }));
$("tools").addEventListener("click", (e) => {
  const row = e.target.closest("tr[data-tool]");
  if (!row) return;
  if (e.target.classList.contains("tool-save")) saveTool(row);
  else if (e.target.classList.contains("tool-remove")) send({ cmd: "tool_remove", number: Number(row.dataset.tool) });
});
$("tool-add").addEventListener("click", () => {
  const number = Number($("tool-new").value);
  send({ cmd: "tool", number, offsets: [0, 0, 0, 0, 0, 0], diameter: 0, comment: "" });
});
$("nc-load").addEventListener("click", () => { $("access").textContent = ""; send({ cmd: "load", program: Number($("program-choice").value) }); });
$("nc-start").addEventListener("click", () => send({ cmd: "program", what: "start" }));
$("nc-hold").addEventListener("click", () => send({ cmd: "program", what: "hold" }));
$("nc-resume").addEventListener("click", () => send({ cmd: "program", what: "resume" }));
// The confirmation names the tool and the change it answers: a late second click cannot
// confirm the next change.
$("tool-changed").addEventListener("click", () => send({ cmd: "tool_changed", tool: toolAsked.tool, change: toolAsked.change }));
$("touch-off").addEventListener("click", () => {
  send({ cmd: "touch_off", system: Number($("touch-system").value), axis: $("touch-axis").value, value: Number($("touch-value").value) });
});
for (const id of ["feed", "rapid", "spindle"]) {
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
$("jog-speed").addEventListener("input", (e) => { $("jog-speed-value").textContent = `${e.target.value} %`; });
$("view3d").addEventListener("change", () => { view3d.on = $("view3d").checked; redraw(true); });
// The 3-D view: dragged to turn, the wheel zooms.
$("path-tool").addEventListener("pointerdown", (e) => {
  if (!view3d.on) return;
  $("path-tool").setPointerCapture(e.pointerId);
  view3d.drag = [e.clientX, e.clientY];
});
$("path-tool").addEventListener("pointermove", (e) => {
  if (!view3d.drag) return;
  view3d.yaw += (e.clientX - view3d.drag[0]) * 0.01;
  view3d.pitch = Math.max(0, Math.min(Math.PI / 2, view3d.pitch + (e.clientY - view3d.drag[1]) * 0.01));
  view3d.drag = [e.clientX, e.clientY];
  redraw(true);
});
for (const end of ["pointerup", "pointercancel", "lostpointercapture"]) $("path-tool").addEventListener(end, () => { view3d.drag = null; });
$("path-tool").addEventListener("wheel", (e) => {
  if (!view3d.on) return;
  e.preventDefault();
  view3d.zoom = Math.max(0.2, Math.min(20, view3d.zoom * Math.exp(-e.deltaY * 0.001)));
  redraw(true);
}, { passive: false });
// The process image's table is written only while it is in view.
new IntersectionObserver((entries) => { watchVisible = entries.some((e) => e.isIntersecting); }).observe($("watch-box"));
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
