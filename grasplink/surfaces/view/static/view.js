// grasplink live view: frames from /events (Server-Sent Events, 10 a second) are kept as
// they come and drawn at most once per animation frame (requestAnimationFrame), so the
// page does as much work as the screen shows, however fast frames arrive.
// Everything from the broker is untrusted text: it goes into the page as textContent only.
"use strict";

const SERVER_AWAY_MS = 2000; // no frame this long (they come every 100 ms): the server is gone
const CODES = {
  belt: { none: 0, force: 1, slip: 2 },
  reflex: { idle: 0, active: 1, hold: 2, release: 3 },
};
// Each plot: its title, the node kind whose values it draws, its series (field, label,
// scale, colour), and its scales' units; `code` maps text states to numbers.
const PLOTS = [
  { title: "skin: grip force and decoded slip speed", kind: "skin", series: [
    ["grip_force_n", "grip force (N)", "n", "#1f77b4"],
    ["slip_speed_mm_s", "slip speed (mm/s)", "v", "#d62728"],
    ["slip_speed_low_mm_s", "speed low (mm/s)", "v", "#f4a3a3"],
  ], units: { n: "N", v: "mm/s" } },
  // `confidence` is the decoder's, of the whole estimate; the direction has its own
  // (docs/decoding.md): both named so, never a bare "confidence"
  { title: "skin: slip position, estimate and direction confidence", kind: "skin", series: [
    ["position_mm", "position (mm)", "mm", "#2ca02c"],
    ["confidence", "estimate confidence (0..1)", "c", "#9467bd"],
    ["slip_direction_confidence", "direction confidence (0..1)", "c", "#17becf"],
    ["slip", "slip (0/1)", "c", "#d62728"],
  ], units: { mm: "mm", c: "0..1" } },
  { title: "belt: commanded velocity, level, active belt", kind: "belt", series: [
    ["velocity_mrad_s", "velocity (mrad/s)", "w", "#ff7f0e"],
    ["level", "level", "l", "#1f77b4"],
    ["belt", "belt (0 none, 1 force, 2 slip)", "l", "#7f7f7f"],
  ], units: { w: "mrad/s", l: "level" } },
  { title: "hand: grip setpoint, reported grip, reflex", kind: "hand", series: [
    ["setpoint_n", "setpoint (N)", "n", "#1f77b4"],
    ["grip_n", "grip (N)", "n", "#2ca02c"],
    ["reflex", "reflex (0 idle, 1 active, 2 hold, 3 release)", "r", "#d62728"],
  ], units: { n: "N", r: "state" } },
  { title: "EMG: envelope and level", kind: "emg", series: [
    ["envelope_uv", "envelope (µV)", "u", "#8c564b"],
    ["level", "level (e0..e5)", "l", "#17becf"],
  ], units: { u: "µV", l: "level" } },
  { title: "loop latency (skin TPDO to RPDOs)", kind: "loop", series: [
    ["latency_p50_us", "p50 (µs)", "us", "#1f77b4"],
    ["latency_p99_us", "p99 (µs)", "us", "#d62728"],
  ], units: { us: "µs" } },
];

const $ = (id) => document.getElementById(id);
// A recording (`grasplink view DIR`): the server says so in the page. It is played with the
// truth beside the decoded values (dashed), and the page says it is a recording, never live.
const recordingMeta = document.querySelector('meta[name="grasplink-recording"]');
const RECORDING = recordingMeta && recordingMeta.content ? JSON.parse(recordingMeta.content) : null;
function plotDrawing(field) { return PLOTS.find((p) => p.series.some(([f]) => f === field)); }
plotDrawing("slip_speed_mm_s").truth = [["speed_mm_s", "true |speed| (mm/s)", "v", "#444444"]];
plotDrawing("position_mm").truth = [
  ["position_mm", "true position (mm)", "mm", "#2ca02c"],
  ["slipping", "truly slipping (0/1)", "c", "#d62728"],
];
plotDrawing("grip_n").truth = [["grip_n", "true grip (N)", "n", "#2ca02c"]];
let latest = null; // the last frame's summary
let lastFrameAt = 0; // performance.now() of the last frame
let history = {}; // gateway -> kind -> {t: [...s], fields: {name: [...]}}
let historyS = 30;
let chosen = new URLSearchParams(location.search).get("gateway");
let drawQueued = false;
let lastSlip = {}; // gateway -> the last skin values with a slip and its speed (or floor)
const plots = [];
// what the page did, for the browser tests: frames taken, draws made (at most one per frame)
window.viewStats = { frames: 0, draws: 0 };

function numeric(kind, field, value) {
  if (value === null || value === undefined) return null;
  if (typeof value === "boolean") return value ? 1 : 0;
  if (typeof value === "string") {
    const code = (CODES[field] || {})[value];
    return code === undefined ? null : code;
  }
  return value;
}

// The speed a slip is shown with: the decoded speed, else the floor of the range of speeds
// still possible (what the belt shows and the reflex acts on until a speed is known).
function shownSpeed(skin) {
  return typeof skin.slip_speed_mm_s === "number" ? skin.slip_speed_mm_s : skin.slip_speed_low_mm_s;
}

function speedText(skin) {
  if (typeof skin.slip_speed_mm_s === "number") return fixed(skin.slip_speed_mm_s, 1, " mm/s");
  if (typeof skin.slip_speed_low_mm_s !== "number") return fixed(null, 1, " mm/s");
  const high = typeof skin.slip_speed_high_mm_s === "number" ? `–${fixed(skin.slip_speed_high_mm_s, 1, "")}` : "+";
  return `≥ ${fixed(skin.slip_speed_low_mm_s, 1, " mm/s")} (range ${fixed(skin.slip_speed_low_mm_s, 1, "")}${high})`;
}

function keep(gateway, kind, tsMs, values) {
  if (kind === "skin" && values.slip && typeof shownSpeed(values) === "number") {
    lastSlip[gateway] = { tsMs, ...values }; // a slip lasts a second or two: keep it in view
  }
  const byKind = (history[gateway] ||= {});
  const h = (byKind[kind] ||= { t: [], fields: {} });
  const t = tsMs / 1000;
  // a message replayed after an outage can be older than the newest: keep time order
  let at = h.t.length;
  while (at > 0 && h.t[at - 1] > t) at--;
  h.t.splice(at, 0, t);
  for (const [field, value] of Object.entries(values)) {
    const column = (h.fields[field] ||= new Array(h.t.length - 1).fill(null));
    column.splice(at, 0, numeric(kind, field, value));
  }
  for (const [field, column] of Object.entries(h.fields)) {
    if (column.length < h.t.length) column.splice(at, 0, null); // absent from this message
  }
}

function trim(h, from) {
  let n = 0;
  while (n < h.t.length && h.t[n] < from) n++;
  if (n === 0) return;
  h.t.splice(0, n);
  for (const column of Object.values(h.fields)) column.splice(0, n);
}

function onFrame(frame) {
  lastFrameAt = performance.now();
  window.viewStats.frames++;
  if (frame.reset) { history = {}; lastSlip = {}; }
  historyS = frame.history_s;
  for (const [gateway, kind, tsMs, values] of frame.points) keep(gateway, kind, tsMs, values);
  latest = frame;
  queueDraw();
}

function queueDraw() {
  if (drawQueued) return;
  drawQueued = true;
  requestAnimationFrame(() => { drawQueued = false; draw(); });
}

function text(node, value) {
  if (node.textContent !== value) node.textContent = value;
}

function fixed(value, digits, unit) {
  return value === null || value === undefined ? "–" : `${Number(value).toFixed(digits)}${unit}`;
}

function chooseGateway(frame) {
  const ids = Object.keys(frame.gateways);
  const select = $("gateway");
  if (select.dataset.ids !== ids.join(",")) {
    select.replaceChildren(...ids.map((id) => new Option(id, id)));
    select.dataset.ids = ids.join(",");
  }
  if (!ids.includes(chosen)) chosen = ids.length ? ids[0] : null;
  if (chosen !== null) select.value = chosen;
  return chosen;
}

function banner(state, message) {
  const node = $("banner");
  node.dataset.state = state;
  text(node, message);
  document.body.classList.toggle("stale", state !== "live" && state !== "recording");
  document.body.classList.toggle("waiting", state === "waiting");
}

function judge(frame, gateway) {
  // in order: the server, the broker, the gateway's status, the age of its last message
  if (performance.now() - lastFrameAt > SERVER_AWAY_MS) {
    return ["server-away", "view server not answering: this page is stale"];
  }
  if (!frame.broker.connected) {
    const since = frame.broker.for_s === null ? "" : ` for ${frame.broker.for_s.toFixed(0)} s`;
    return ["broker-away", `broker away${since}: ${frame.broker.error || "not connected yet"}`];
  }
  if (gateway === null) return ["waiting", "connected; no gateway has published yet"];
  const g = frame.gateways[gateway];
  if (g.online === false) return ["offline", `gateway ${gateway} offline (${g.offline_reason})`];
  if (g.stale) {
    const age = g.age_s === null ? "ever" : `${g.age_s.toFixed(1)} s`;
    return ["stale", `stale: nothing from ${gateway} for ${age} (bound ${frame.stale_after_s} s)`];
  }
  return ["live", `live: ${gateway}`];
}

function cell(value, cls) {
  const td = document.createElement("td");
  td.textContent = value === null || value === undefined ? "–" : String(value);
  if (cls) td.className = cls;
  return td;
}

// The age of a node's last heartbeat (at the gateway's last health), flagged when older
// than the gateway's consumer time: the gateway loses a node that silent.
function heartbeatCell(n) {
  const td = cell(fixed(n.heartbeat_age_s, 2, " s"), "num heartbeat");
  if (n.heartbeat_overdue) {
    td.dataset.overdue = "true";
    td.title = `older than the gateway's consumer time (${n.heartbeat_consumer_ms} ms)`;
  }
  return td;
}

function drawNodes(g) {
  const body = $("nodes").tBodies[0];
  const rows = Object.entries(g.nodes).map(([name, n]) => {
    const tr = document.createElement("tr");
    tr.dataset.node = name;
    tr.dataset.phase = n.phase || "unknown";
    tr.append(
      cell(name), cell(n.node_id, "num"), cell(n.phase, "phase"), cell(n.nmt_state),
      heartbeatCell(n), cell(fixed(n.values_age_s, 1, " s"), "num"), cell(n.loss_lost_packets, "num"),
      cell(n.loss_pdos_dropped, "num"), cell(n.times_lost ?? n.loss_times_lost, "num"),
      cell(n.last_emcy),
    );
    return tr;
  });
  const key = rows.map((r) => r.outerHTML).join("");
  if (body.dataset.key !== key) {
    body.replaceChildren(...rows);
    body.dataset.key = key;
  }
}

function drawAlarms(g) {
  const entries = Object.entries(g.alarms);
  text($("alarm-count"), String(entries.length));
  const key = JSON.stringify(entries);
  const list = $("alarms");
  if (list.dataset.key === key) return;
  list.dataset.key = key;
  list.replaceChildren(...entries.map(([k, v]) => {
    const li = document.createElement("li");
    li.dataset.alarm = k;
    li.textContent = `${k}: ${v}`;
    return li;
  }));
}

function drawNow(g) {
  const skin = (g.nodes.skin || {}).values || {};
  const slip = $("slip");
  slip.dataset.slip = skin.slip === undefined || skin.slip === null ? "unknown" : String(skin.slip);
  slip.dataset.speed = shownSpeed(skin) ?? "";
  if (skin.slip) {
    const way = skin.slip_direction === null || skin.slip_direction === undefined ? "direction –"
      : `direction ${skin.slip_direction > 0 ? "+" : "−"} (confidence ${fixed(skin.slip_direction_confidence, 2, "")})`;
    text(slip, `SLIP ${speedText(skin)} at ${fixed(skin.position_mm, 1, " mm")}` +
      `, ${way}; estimate confidence ${fixed(skin.confidence, 2, "")}`);
  } else {
    text(slip, skin.slip === false ? `no slip; grip ${fixed(skin.grip_force_n, 2, " N")}` : "slip: –");
  }
  const last = lastSlip[chosen];
  const shown = $("last-slip");
  shown.dataset.speed = last ? shownSpeed(last) : "";
  const when = last && (RECORDING ? `${(last.tsMs / 1000).toFixed(2)} s in the run`
    : new Date(last.tsMs).toLocaleTimeString());
  const truth = last && RECORDING ? trueSpeedAt(last.tsMs / 1000) : null;
  shown.dataset.truth = truth === null ? "" : String(truth);
  text(shown, last ? `last slip with a speed: ${speedText(last)} at ` +
    when + (truth === null ? "" : ` (true ${fixed(truth, 1, " mm/s")})`)
    : "last slip with a speed: –");
  const hand = (g.nodes.hand || {}).values || {};
  $("reflex").dataset.reflex = hand.reflex || "unknown";
  text($("reflex"), `reflex: ${hand.reflex || "–"} (${hand.source || "–"})`);
}

function trueSpeedAt(t) {
  // a recording's truth.csv speed at time t in the run (the last point at or before it)
  const h = (history[chosen] || {}).truth;
  if (!h || !h.fields.speed_mm_s) return null;
  let i = h.t.length - 1;
  while (i >= 0 && h.t[i] > t) i--;
  return i < 0 ? null : h.fields.speed_mm_s[i];
}

function makePlots() {
  const box = $("plots");
  for (const spec of PLOTS) {
    const div = document.createElement("div");
    div.className = "plot";
    div.dataset.kind = spec.kind;
    const h3 = document.createElement("h3");
    h3.textContent = spec.title;
    div.append(h3);
    box.append(div);
    const scales = { x: { time: RECORDING === null, range: () => plotWindow } };
    const axes = [RECORDING ? { label: "s in the run" } : {}];
    const truth = (RECORDING && spec.truth) || [];
    Object.entries(spec.units).forEach(([scale, unit], i) => {
      scales[scale] = { auto: true };
      axes.push({ scale, label: unit, side: i === 0 ? 3 : 1, grid: { show: i === 0 } });
    });
    const opts = {
      width: Math.max(300, div.clientWidth || 460), height: 170, scales, axes,
      series: [{}, ...spec.series.map(([, label, scale, stroke]) => ({ label, scale, stroke, width: 1.5 })),
        ...truth.map(([, label, scale, stroke]) =>
          ({ label, scale, stroke, width: 1.5, dash: [6, 4], spanGaps: true }))],
      cursor: { show: false }, legend: { live: false },
    };
    const empty = [[], ...spec.series.map(() => []), ...truth.map(() => [])];
    plots.push({ spec, div, truth, plot: new uPlot(opts, empty, div) });
  }
  window.addEventListener("resize", () => {
    for (const p of plots) p.plot.setSize({ width: Math.max(300, p.div.clientWidth), height: 170 });
  });
}

let plotWindow = [0, 1];

function drawPlots(gateway, g) {
  const byKind = history[gateway] || {};
  const end = g.newest_ts_ms / 1000; // the gateway's clock: a skewed host still scrolls right
  plotWindow = [end - historyS, end];
  if (RECORDING && latest.recording) { // the run's time: its first 30 s fill the plot as played
    const at = latest.recording.position_s;
    plotWindow = [Math.max(0, at - historyS), Math.max(at, Math.min(RECORDING.duration_s, historyS))];
  }
  for (const h of Object.values(byKind)) trim(h, end - historyS - 1);
  for (const { spec, plot, truth } of plots) {
    const h = byKind[spec.kind] || { t: [], fields: {} };
    const data = [h.t, ...spec.series.map(([field]) => h.fields[field] || h.t.map(() => null))];
    if (truth.length === 0) { plot.setData(data); continue; }
    // the truth has its own times (truth.csv): both tables on one x (gaps where one has none)
    const tt = byKind.truth || { t: [], fields: {} };
    plot.setData(uPlot.join([data, [tt.t, ...truth.map(([f]) => tt.fields[f] || tt.t.map(() => null))]]));
  }
}

function draw() {
  const frame = latest;
  if (frame === null) return;
  window.viewStats.draws++;
  const gateway = chooseGateway(frame);
  const [state, message] = judge(frame, gateway);
  if (RECORDING && frame.recording) drawRecording(frame.recording, state, message);
  else banner(state, message);
  text($("problems"), String(frame.problems + (gateway ? frame.gateways[gateway].problems : 0)));
  const last = (gateway && frame.gateways[gateway].last_problem) || frame.last_problem;
  text($("last-problem"), last ? `last: ${last}` : "");
  if (gateway === null) return;
  const g = frame.gateways[gateway];
  text($("age"), fixed(g.age_s, 1, " s"));
  text($("p50"), fixed(g.health.loop_latency_p50_us, 0, " µs"));
  text($("p99"), fixed(g.health.loop_latency_p99_us, 0, " µs"));
  text($("mode"), g.controls.feedback_mode || "–");
  text($("uptime"), fixed(g.health.uptime_s, 0, " s"));
  text($("messages"), String(g.messages));
  drawNodes(g);
  drawAlarms(g);
  drawNow(g);
  drawPlots(gateway, g);
}

function connect() {
  if (RECORDING) { play(playing); return; }
  const events = new EventSource("/events");
  events.onmessage = (event) => onFrame(JSON.parse(event.data));
  // EventSource reconnects by itself (retry: 1 s); the watch below greys the page meanwhile
}

// Playback of a recording: the server keeps each page's clock, set by the stream's query;
// pause, play, seek and speed open a new stream from where the page is (its history reset).
let playing = { at: 0, rate: 1, paused: false };
let stream = null;
let seeking = false; // while the slider is held, frames do not move it

function play(next) {
  playing = next;
  if (stream !== null) stream.close();
  const query = `at=${next.at.toFixed(3)}&rate=${next.rate}&paused=${next.paused ? 1 : 0}`;
  stream = new EventSource(`/events?${query}`);
  stream.onmessage = (event) => onFrame(JSON.parse(event.data));
  // a lost stream is reopened from where the page was, not from the last control's time
  stream.onerror = () => {
    stream.close();
    stream = null;
    setTimeout(() => { if (stream === null) play({ ...playing, at: shownPosition() }); }, 1000);
  };
}

function shownPosition() {
  return latest && latest.recording ? latest.recording.position_s : playing.at;
}

function drawRecording(r, state, message) {
  // never live: the banner says recording, the folder and the time in the run
  const where = `${r.position_s.toFixed(2)} s of ${r.duration_s.toFixed(2)} s`;
  const how = r.ended ? "ended" : r.paused ? "paused" : `playing ×${r.rate}`;
  const note = state === "live" ? "" : ` (${message})`;
  banner(state === "server-away" ? state : "recording",
    `recording ${r.folder}: ${where}, ${how}${note}`);
  $("banner").dataset.position = String(r.position_s);
  $("banner").dataset.paused = String(r.paused);
  text($("run-time"), where);
  text($("play"), r.paused || r.ended ? "play" : "pause");
  if (!seeking) $("seek").value = String(r.position_s);
}

function makePlayback() {
  if (RECORDING === null) return;
  document.title = `grasplink recording ${RECORDING.folder}`;
  document.querySelector("h1").textContent = "grasplink recording";
  $("playback").hidden = false;
  $("seek").max = String(RECORDING.duration_s);
  $("rate").replaceChildren(...RECORDING.rates.map((r) => new Option(`×${r}`, String(r))));
  $("rate").value = "1";
  text($("settings"), RECORDING.settings);
  $("footer").textContent = "a recording replayed through the gateway's decoding (docs/view.md): " +
    "nothing here is live";
  $("play").addEventListener("click", () => {
    const r = latest && latest.recording;
    const paused = !(r && (r.paused || r.ended));
    play({ ...playing, at: r && r.ended && !paused ? 0 : shownPosition(), paused });
  });
  $("seek").addEventListener("input", () => { seeking = true; });
  $("seek").addEventListener("change", () => {
    seeking = false;
    play({ ...playing, at: Number($("seek").value) });
  });
  $("rate").addEventListener("change", () => {
    play({ ...playing, at: shownPosition(), rate: Number($("rate").value) });
  });
}

// Commands: offered only when the server put its spec and this page's token in the page
// (`grasplink view --allow-commands`). The server checks each with the gateway's own parser
// before publishing it, so a value out of the gateway's limits is refused there, named.
const commandsMeta = document.querySelector('meta[name="grasplink-commands"]');
const COMMAND_SPEC = commandsMeta && commandsMeta.content ? JSON.parse(commandsMeta.content) : null;
const TOKEN = commandsMeta ? commandsMeta.dataset.token : null;
const REPLIES_SHOWN = 10;

function input(type, placeholder) {
  const node = document.createElement("input");
  node.type = type;
  node.placeholder = placeholder;
  if (type === "number") node.step = "any";
  return node;
}

function commandForm(name, spec) {
  const form = document.createElement("form");
  form.dataset.command = name;
  form.title = `${name}: ${spec.expected}`;
  const label = document.createElement("label");
  label.textContent = name;
  const fields = [];
  let read;
  if (spec.choices) {
    const select = document.createElement("select");
    select.append(...spec.choices.map((c) => new Option(String(c), String(c))));
    fields.push(select);
    read = () => spec.choices[select.selectedIndex];
  } else if (spec.number) {
    const box = input("number", `${spec.number[0]}..${spec.number[1]}`);
    fields.push(box);
    read = () => (box.value === "" ? null : Number(box.value));
  } else {
    const boxes = spec.pair.map((key) => input("number", key));
    fields.push(...boxes);
    read = () => Object.fromEntries(spec.pair.map((key, i) =>
      [key, boxes[i].value === "" ? null : Number(boxes[i].value)]));
  }
  const button = document.createElement("button");
  button.textContent = "send";
  form.append(label, ...fields, button);
  form.addEventListener("submit", (event) => { event.preventDefault(); send(name, read()); });
  return form;
}

function showReply(name, value, answer) {
  const li = document.createElement("li");
  li.dataset.command = name;
  li.dataset.accepted = String(answer.accepted === true);
  li.dataset.by = answer.by || "";
  const verdict = answer.accepted ? "accepted" : `refused by the ${answer.by || "view"}`;
  li.textContent = `${new Date().toLocaleTimeString()} ${name} ${JSON.stringify(value)}: ` +
    `${verdict}: ${answer.detail}`;
  const list = $("command-replies");
  list.prepend(li);
  while (list.children.length > REPLIES_SHOWN) list.lastChild.remove();
}

async function send(name, value) {
  let answer;
  try {
    const response = await fetch("/command", {
      method: "POST",
      headers: { "Content-Type": "application/json", "X-Grasplink-Token": TOKEN },
      body: JSON.stringify({ gateway: chosen, command: name, value }),
    });
    answer = response.ok ? await response.json()
      : { accepted: false, by: "view server", detail: (await response.text()).trim() };
  } catch (error) {
    answer = { accepted: false, by: "page", detail: `the view server did not answer (${error.message})` };
  }
  showReply(name, value, answer);
}

function makeCommands() {
  if (COMMAND_SPEC === null) return;
  $("commands").hidden = false;
  $("footer").textContent = "commands allowed: each is checked against the gateway's limits " +
    "before it is sent (docs/view.md)";
  $("command-forms").append(...Object.entries(COMMAND_SPEC).map(([n, s]) => commandForm(n, s)));
}

$("gateway").addEventListener("change", (event) => { chosen = event.target.value; queueDraw(); });
setInterval(() => {
  if (latest !== null && performance.now() - lastFrameAt > SERVER_AWAY_MS) {
    banner("server-away", "view server not answering: this page is stale");
  }
}, 500);
makePlayback();
makePlots();
makeCommands();
connect();
