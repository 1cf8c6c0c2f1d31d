// hermsd's page: the tun now, its last hours, and the changes a logged-in brewer may make.
// The server pushes each control period as a server-sent event; a change goes to
// /api/command with the session's CSRF token, and the daemon's own checks decide.
// A HERMS's mash sensor adds the mash temperature as the chart's second line and the HLT's
// setpoint the outer loop chose as a dashed one (the setpoint shown is then the mash's), and
// its pump shows its state and a start/stop button (the state alone for a pump hermsd only
// sees); a tun without them shows neither.
// Each event says how old its reading is: the page counts on from there, shows "live" only
// while the reading is younger than the event's stale_after (two control periods) and the
// daemon answers, and else says "no daemon" or the reading's age in red, every command off.
"use strict";

const $ = (id) => document.getElementById(id);
let session = { logged_in: false, csrf: null, can_log_in: false, view_open: false };
// The chart's columns, in the daemon's seconds (t); x = t + offset (the wall clock).
const T = [], PV = [], SP = [], OUT = [], MASH = [], HLT_SP = [];
const MASH_SERIES = { label: "Mash °C", stroke: "#2e7d32", width: 2, scale: "°C" };
const HLT_SP_SERIES = {
  label: "HLT setpoint °C", stroke: "#ef6c00", width: 1.5, dash: [2, 3], scale: "°C",
};
let mashFitted = false; // whether the daemon reads a mash sensor: the chart has its lines
let offset = 0;
let band = 0; // °C either side of the setpoint that counts as holding it (the server says)
let rangeHours = 3;
let chart = null;
let source = null;
let viewing = false;
let lastPushedT = -Infinity; // of the last status pushed (a command's reply may be newer)
let shownT = -Infinity; // of the status shown: one pushed before a command's reply is older
let shownAlarms = []; // the alarms the page shows: what its reset button clears
let shownWarnings = []; // the warnings the page shows
let programRuns = false; // whether a program runs (not done): the screen is kept on
let shownStep = null; // the program step the page shows: what its confirm and next end
let shownPump = null; // the pump's state the page shows (null: none fitted)
let reading = null; // the reading shown: its age (s) when it came, and Date.now() then
let staleAfter = 0; // s a reading stays live (from the server's events)
let daemonDown = null; // why the daemon does not answer (the server says), or null
let streaming = false; // whether the event stream is open
const busy = new Set(); // the buttons whose command is on its way

async function api(path, body) {
  const options = { credentials: "same-origin" };
  if (body !== undefined) {
    options.method = "POST";
    options.headers = { "Content-Type": "application/json" };
    if (session.csrf) options.headers["X-CSRF-Token"] = session.csrf;
    options.body = JSON.stringify(body);
  }
  let response;
  try {
    response = await fetch(path, options);
  } catch (error) {
    return { status: 0, body: { error: "the page's server cannot be reached" } };
  }
  let json = {};
  try { json = await response.json(); } catch (error) { /* not JSON: status says enough */ }
  return { status: response.status, body: json };
}

function say(text, kind) {
  const message = $("message");
  message.textContent = text;
  message.className = kind || "";
}

function fixed(value, digits, unit) {
  return value === null || value === undefined ? "—" : `${value.toFixed(digits)} ${unit}`;
}

function duration(seconds) {
  if (seconds === null || seconds === undefined) return "—";
  const s = Math.max(0, Math.round(seconds));
  const h = Math.floor(s / 3600), m = Math.floor((s % 3600) / 60), r = s % 60;
  return h ? `${h} h ${m} min` : m ? `${m} min ${r} s` : `${r} s`;
}

// `age`: s the reading was old when it came (a command's reply: 0, just made).
function render(status, age) {
  reading = { age, at: Date.now() };
  shownT = status.t;
  window.lastStatus = status;
  document.body.dataset.t = String(status.t);
  $("tun").textContent = status.tun;
  $("pv").textContent = fixed(status.pv, 2, "°C");
  $("setpoint").textContent = fixed(status.setpoint, 1, "°C");
  $("output").textContent = fixed(status.output, 0, "%");
  $("output2-box").hidden = status.output2 === null || status.output2 === undefined;
  $("output2").textContent = fixed(status.output2, 0, "%");
  $("mode").textContent = status.mode === "manual"
    ? `manual at ${status.manual_output} %` : status.mode;
  $("state").textContent = status.state;
  const alarms = status.alarms || [];
  shownAlarms = alarms;
  $("alarm-box").hidden = alarms.length === 0;
  const reasons = status.alarm_reasons || {};  // why each stands: what the brewer must check
  $("alarms").textContent = alarms
    .map((kind) => (reasons[kind] ? `${kind}: ${reasons[kind]}` : kind)).join("; ");
  const latched = status.latched || [];  // the others clear themselves: no reset for them
  const passing = alarms.filter((kind) => !latched.includes(kind));
  $("alarm-note").textContent = passing.length
    ? `(${passing.join(", ")}: the heater is off until it is over)` : "";
  $("reset-alarm").hidden = latched.length === 0;
  const warnings = status.warnings || [];  // nothing held off, but the brewer should look
  shownWarnings = warnings;
  $("warning-box").hidden = warnings.length === 0;
  $("warnings").textContent = warnings.join("; ");
  renderProgram(status.program, status.pv);
  renderMashSide(status.mash, status.pump, status.pump_switched);
  renderCurrent(status.current);
  if (document.activeElement !== $("setpoint-input") && !$("setpoint-input").value) {
    $("setpoint-input").placeholder = String(status.setpoint);
  }
  showFreshness();
}

// The daemon's estimate by the tun's model: minutes are all it can honestly say.
function restIn(seconds) {
  if (seconds < 60) return "rest starts in under a minute";
  const minutes = Math.round(seconds / 60);
  const h = Math.floor(minutes / 60), m = minutes % 60;
  return `rest starts in about ${h ? `${h} h ${m} min` : `${m} min`}`;
}

// `pv`: the HLT's; above the step's setpoint, the program's "heating" is a cool-down.
function renderProgram(program, pv) {
  $("program-box").hidden = !program;
  $("program-form").hidden = Boolean(program); // one program at a time: stop it to start another
  programRuns = Boolean(program) && program.state !== "done";
  shownStep = program && program.step ? program.step.index : null;
  if (!program) return;
  $("program-name").textContent = program.name;
  const step = program.step;
  const cooling = program.state === "heating" && step && typeof pv === "number"
    && pv > step.setpoint;
  $("program-state").textContent = cooling ? "cooling" : program.state;
  $("program-step").textContent = step
    ? `${step.index + 1} of ${program.steps}: ${step.name}, ${step.setpoint} °C` : "—";
  $("program-left").textContent = program.state === "scheduled" && program.starts_at
    ? `starts ${new Date(program.starts_at).toLocaleTimeString()}`
    : typeof program.rest_in_s === "number" ? restIn(program.rest_in_s)
    : program.time_left_s === null ? "until in band, or told" : duration(program.time_left_s);
  $("program-next").textContent = program.next || "last step";
  const waiting = program.state === "waiting";
  $("program-message").hidden = !waiting;
  $("program-message").textContent = waiting ? `Waiting: ${program.message || "confirm"}` : "";
  $("program-confirm").hidden = !waiting;
  $("program-pause").hidden = program.state === "paused" || program.state === "done";
  $("program-resume").hidden = program.state !== "paused";
}

// `current`: null when no element-current input is fitted, else its latest sample: the
// amps a current transformer measured (null from a mains-present input, which says only
// whether the element is powered) against the SSR's command then, and its warning.
function renderCurrent(current) {
  $("current-box").hidden = !current;
  if (!current) return;
  const asked = current.on === null ? "" : ` (SSR ${current.on ? "on" : "off"})`;
  const drawn = typeof current.amps === "number" ? `${current.amps.toFixed(1)} A`
    : current.drawing === null ? "—" : current.drawing ? "powered" : "off";
  $("current").textContent = current.warning ? "not judging" : `${drawn}${asked}`;
  $("current").title = current.warning || "";
}

// `mash`: null when no mash sensor is fitted, else its reading (null while faulty) and fault,
// and the HLT's setpoint the outer loop chose with its phase (null before its first period);
// `pump`: null when none is fitted or seen; `switched` false for one hermsd only sees.
function renderMashSide(mash, pump, switched) {
  $("mash-box").hidden = !mash;
  $("hlt-aim-box").hidden = !mash;
  $("setpoint-label").textContent = mash ? "Mash setpoint" : "Setpoint";
  if (mash) {
    $("mash").textContent = mash.fault ? "sensor fault" : fixed(mash.celsius, 1, "°C");
    $("mash").title = mash.fault || "";
    const aim = typeof mash.hlt_setpoint === "number" ? mash.hlt_setpoint : null;
    $("hlt-aim").textContent = aim === null ? "—"
      : `→ ${aim.toFixed(1)} °C${mash.phase ? ` (${mash.phase})` : ""}`;
  }
  showMashLine(Boolean(mash));
  // A start hermsd prepares (the coil's load sent ahead) is the pump asked on: the button
  // says "Stop pump", which cancels it.
  const startIn = mash && typeof mash.pump_start_in === "number" ? mash.pump_start_in : null;
  const starting = pump === false && startIn !== null;
  shownPump = typeof pump === "boolean" ? pump || starting : null;
  $("pump-box").hidden = shownPump === null;
  $("pump-row").hidden = shownPump === null || switched === false; // seen, not switched
  // The program's pump timer: when it next turns the pump (as the status line says it).
  const turnIn = mash && typeof mash.pump_turn_in === "number" ? mash.pump_turn_in : null;
  const timer = turnIn === null ? ""
    : `, ${shownPump ? "off" : "on"} in ${turnIn < 120 ? `${turnIn.toFixed(0)} s`
      : `${(turnIn / 60).toFixed(0)} min`} (timer)`;
  $("pump").textContent = starting ? `starting in ${startIn.toFixed(0)} s`
    : `${shownPump ? "on" : "off"}${timer}`;
  $("pump-button").textContent = shownPump ? "Stop pump" : "Start pump";
}

function showMashLine(fitted) {
  if (fitted === mashFitted || !chart) return;
  mashFitted = fitted;
  if (fitted) {
    chart.addSeries(MASH_SERIES, 4);
    chart.addSeries(HLT_SP_SERIES, 5);
  } else {
    chart.delSeries(5);
    chart.delSeries(4);
  }
  chart.setData(columns());
}

function readingAge() {
  return reading === null ? null : reading.age + (Date.now() - reading.at) / 1000;
}

// Whether the reading shown may be taken as the tun now: what commands are sent against.
function live() {
  const age = readingAge();
  return streaming && daemonDown === null && age !== null && age <= staleAfter;
}

function showFreshness() {
  const age = readingAge();
  const old = age === null ? "" : `reading ${Math.round(age)} s old`;
  let text = old;
  if (daemonDown !== null) text = "no daemon";
  else if (!streaming) text = "reconnecting…";
  else if (age === null) text = "connecting…";
  else if (live()) text = "live";
  const fresh = live();
  $("conn").textContent = text;
  $("conn").className = fresh ? "conn live" : age === null && daemonDown === null
    ? "conn" : "conn down";
  $("conn").title = daemonDown || "";
  $("age").textContent = age === null ? "—" : `${Math.round(age)} s old`;
  $("view").classList.toggle("stale", !fresh);
  updateCommands();
  attend(age);
}

// The brewer's attention: what a phone on the bench or in a pocket must learn. While an alarm
// stands or the page has no live reading: a full-width banner, the title and the icon changed,
// and every ALERT_EVERY_MS a vibration and, once the brewer has turned the sound on (a browser
// plays audio only after a tap), a beep; the screen kept on while that lasts or a program runs.
const ALERT_EVERY_MS = 2000;
const ICON_COLOURS = { ok: "#256c2b", check: "#b07d00", alarm: "#b3261e" };
let audio = null; // the AudioContext, made by the tap that turns the sound on
let soundOn = false;
let alertTimer = null; // the beeping and vibrating, while alerting
let beeps = 0;
let wakeLock = null; // the screen's WakeLockSentinel; "asking" or "refused" until visible again
let wantAwake = false;

function attend(age) {
  const lost = daemonDown !== null || (age !== null && age > staleAfter);
  $("lost-box").hidden = !lost;
  $("lost").textContent = daemonDown !== null
    ? "the daemon does not answer: nothing on this page is the tun now"
    : `the last reading is ${Math.round(age)} s old: nothing on this page is the tun now`;
  const alarm = shownAlarms.length > 0;
  const level = alarm || lost ? "alarm" : shownWarnings.length ? "check" : "ok";
  const word = alarm ? "ALARM" : lost ? (daemonDown !== null ? "NO DAEMON" : "NOT LIVE")
    : level === "check" ? "check" : "";
  const title = level === "ok" ? "hermsd" : `${level === "alarm" ? "⚠ " : ""}${word} — hermsd`;
  if (document.title !== title) document.title = title;
  showIcon(level);
  if (level === "alarm" && alertTimer === null) {
    alertOnce();
    alertTimer = setInterval(alertOnce, ALERT_EVERY_MS);
  } else if (level !== "alarm" && alertTimer !== null) {
    clearInterval(alertTimer);
    alertTimer = null;
    if (navigator.vibrate) navigator.vibrate(0);
  }
  keepAwake(level === "alarm" || programRuns);
}

function showIcon(level) {
  let icon = document.querySelector("link[rel=icon]");
  if (!icon) {
    icon = document.createElement("link");
    icon.rel = "icon";
    document.head.appendChild(icon);
  }
  if (icon.dataset.level === level) return;
  const mark = level === "ok" ? "" : "<text x='8' y='13' font-size='12' font-weight='bold' "
    + "text-anchor='middle' fill='white'>!</text>";
  const svg = "<svg xmlns='http://www.w3.org/2000/svg' viewBox='0 0 16 16'><circle cx='8' "
    + `cy='8' r='8' fill='${ICON_COLOURS[level]}'/>${mark}</svg>`;
  icon.href = `data:image/svg+xml,${encodeURIComponent(svg)}`;
  icon.dataset.level = level;
}

function alertOnce() {
  if (soundOn) beep();
  if (navigator.vibrate) navigator.vibrate([400, 200, 400]);
}

// Two short 880 Hz tones: loud, and unlike anything else in a brewery.
function beep() {
  if (!audio || audio.state !== "running") return;
  const now = audio.currentTime;
  for (const at of [0, 0.35]) {
    const tone = audio.createOscillator(), gain = audio.createGain();
    tone.type = "square";
    tone.frequency.value = 880;
    gain.gain.value = 0.3;
    tone.connect(gain).connect(audio.destination);
    tone.start(now + at);
    tone.stop(now + at + 0.25);
  }
  beeps += 1;
}

async function toggleSound() {
  soundOn = !soundOn;
  $("sound").textContent = soundOn ? "Sound: on" : "Sound: off";
  $("sound").setAttribute("aria-pressed", String(soundOn));
  if (!soundOn) return;
  const Context = window.AudioContext || window.webkitAudioContext;
  if (!Context) {
    say("this browser cannot play sound: alarms show and vibrate only", "error");
    return;
  }
  audio = audio || new Context();
  await audio.resume();
  beep(); // at once: the brewer hears how loud an alarm is
}

// Asked for again whenever the page becomes visible: the browser lets the lock go when hidden.
async function keepAwake(wanted) {
  wantAwake = wanted;
  if (!navigator.wakeLock) return;
  if (wanted && wakeLock === null && document.visibilityState === "visible") {
    wakeLock = "asking";
    let lock;
    try {
      lock = await navigator.wakeLock.request("screen");
    } catch (error) { // refused (battery saver, no focus): the page alerts all the same
      wakeLock = "refused";
      return;
    }
    lock.addEventListener("release", () => { if (wakeLock === lock) wakeLock = null; });
    wakeLock = lock;
    if (!wantAwake) keepAwake(false);
  } else if (!wanted && typeof wakeLock === "object" && wakeLock !== null) {
    const lock = wakeLock;
    wakeLock = null;
    lock.release();
  }
}

document.addEventListener("visibilitychange", () => {
  if (wakeLock === "refused") wakeLock = null;
  keepAwake(wantAwake);
});

function updateCommands() {
  const allowed = session.logged_in && live();
  for (const button of document.querySelectorAll(".needs-login")) {
    button.disabled = !allowed || busy.has(button);
  }
}

function columns() {
  const shown = [T.map((t) => t + offset), PV, SP, OUT];
  return mashFitted ? [...shown, MASH, HLT_SP] : shown;
}

function makeChart() {
  const box = $("chart");
  const options = {
    width: Math.max(280, box.clientWidth),
    height: 240,
    cursor: { drag: { x: false, y: false } },
    legend: { live: false },
    scales: {
      x: { time: true, range: (u, min, max) => [Math.max(min, max - rangeHours * 3600), max] },
      "%": { range: [0, 100] },
    },
    series: [
      {},
      { label: "Temperature °C", stroke: "#c62828", width: 2, scale: "°C" },
      { label: "Setpoint °C", stroke: "#1f5fbf", width: 1.5, dash: [6, 4], scale: "°C" },
      { label: "Output %", stroke: "#888", width: 1, scale: "%" },
      ...(mashFitted ? [MASH_SERIES, HLT_SP_SERIES] : []),
    ],
    // Each axis says its unit; the right one is wide enough for "100" on a 390 px phone.
    axes: [
      { label: "local time", ...AXIS_LABEL },
      { scale: "°C", size: 36, label: "°C", ...AXIS_LABEL },
      { scale: "%", side: 1, size: 34, grid: { show: false }, label: "output %", ...AXIS_LABEL },
    ],
    hooks: { drawAxes: [drawBand] },
  };
  chart = new uPlot(options, columns(), box);
  performance.mark("hermsd-chart");
  window.addEventListener("resize", () => chart.setSize({ width: box.clientWidth, height: 240 }));
}

const AXIS_LABEL = { labelSize: 16, labelGap: 0, labelFont: "12px system-ui, sans-serif" };
const BAND_FILL = "rgba(31, 95, 191, 0.15)"; // the setpoint's blue, faint

// The setpoint's ±band drawn under the lines, a step at each change as the setpoint is
// (a gap where it is unknown): in it, the tun holds its setpoint.
function drawBand(u) {
  const xs = u.data[0], setpoints = u.data[2];
  const [first, last] = u.series[0].idxs || [0, xs.length - 1];
  const { left, top, width, height } = u.bbox;
  const ctx = u.ctx;
  ctx.save();
  ctx.beginPath();
  ctx.rect(left, top, width, height);
  ctx.clip();
  ctx.fillStyle = BAND_FILL;
  let run = [];
  for (let i = Math.max(0, first - 1); i <= Math.min(xs.length - 1, last + 1); i++) {
    if (setpoints[i] === null || setpoints[i] === undefined) {
      fillBand(u, run);
      run = [];
    } else {
      run.push(i);
    }
  }
  fillBand(u, run);
  ctx.restore();
}

function fillBand(u, run) {
  if (run.length === 0) return;
  const ctx = u.ctx, xs = u.data[0], setpoints = u.data[2];
  const x = (i) => u.valToPos(xs[i], "x", true);
  const y = (i, side) => u.valToPos(setpoints[i] + side * band, "°C", true);
  ctx.beginPath();
  ctx.moveTo(x(run[0]), y(run[0], 1));
  for (let k = 1; k < run.length; k++) {
    ctx.lineTo(x(run[k]), y(run[k - 1], 1));
    ctx.lineTo(x(run[k]), y(run[k], 1));
  }
  for (let k = run.length - 1; k > 0; k--) {
    ctx.lineTo(x(run[k]), y(run[k], -1));
    ctx.lineTo(x(run[k]), y(run[k - 1], -1));
  }
  ctx.lineTo(x(run[0]), y(run[0], -1));
  ctx.closePath();
  ctx.fill();
}

function addRows(rows) {
  for (const [t, pv, setpoint, output, mash, hltSetpoint] of rows) {
    if (T.length && t <= T[T.length - 1]) continue;
    T.push(t); PV.push(pv); SP.push(setpoint); OUT.push(output); MASH.push(mash);
    HLT_SP.push(hltSetpoint);
  }
  const oldest = T.length ? T[T.length - 1] - 24 * 3600 : 0;
  let cut = 0;
  while (cut < T.length && T[cut] <= oldest) cut++;
  if (cut) {
    for (const column of [T, PV, SP, OUT, MASH, HLT_SP]) column.splice(0, cut);
  }
}

async function loadView() {
  if (viewing) return;
  const response = await api("/api/history");
  if (response.status !== 200) {
    say(response.body.error || `cannot load the history (HTTP ${response.status})`, "error");
    return;
  }
  viewing = true;
  const history = response.body;
  T.length = PV.length = SP.length = OUT.length = MASH.length = HLT_SP.length = 0;
  T.push(...history.t); PV.push(...history.pv); SP.push(...history.setpoint);
  OUT.push(...history.output);
  MASH.push(...history.mash);
  HLT_SP.push(...history.hlt_setpoint);
  offset = history.offset;
  band = history.band;
  $("view").hidden = false;
  if (chart) chart.destroy();
  makeChart();
  connect();
}

function connect() {
  const since = T.length ? `?since=${T[T.length - 1]}` : "";
  source = new EventSource(`/api/events${since}`);
  source.onopen = () => { streaming = true; };
  source.onmessage = (event) => onEvent(JSON.parse(event.data));
  source.onerror = () => {
    source.close();
    streaming = false;
    showFreshness();
    setTimeout(connect, 2000);
  };
}

function onEvent(message) {
  streaming = true;
  if (typeof message.stale_after === "number") staleAfter = message.stale_after;
  if (message.error) {
    if (daemonDown !== message.error) say(message.error, "error");
    daemonDown = message.error;
    showFreshness();
    return;
  }
  daemonDown = null;
  const status = message.status;
  if (status.t < lastPushedT) { // the daemon restarted: its history is new
    source.close();
    viewing = false;
    lastPushedT = -Infinity;
    shownT = -Infinity;
    loadView();
    return;
  }
  lastPushedT = status.t;
  offset = message.offset;
  addRows(message.rows);
  // A status read before a command's reply must not undo what the reply showed.
  if (status.t >= shownT) render(status, typeof message.age === "number" ? message.age : Infinity);
  chart.setData(columns());
}

function updateSessionView() {
  $("login-form").hidden = session.logged_in || !session.can_log_in;
  $("changes").hidden = !session.logged_in;
  updateCommands();
  if (!session.can_log_in && !session.logged_in) {
    say("Viewing only: no password is set for changes (web.password_hash).");
  }
}

// `button`: disabled until the answer is in, so that a second click cannot send the same
// command again for a step the first one has already ended.
async function send(command, what, path = "/api/command", button = null) {
  if (!live()) {
    say(`${what}: not sent: the page has no live reading of the tun`, "error");
    return { status: 0, body: {} };
  }
  say(`${what}…`);
  if (button) busy.add(button);
  updateCommands();
  let response;
  try {
    response = await api(path, command);
  } finally {
    if (button) busy.delete(button);
    updateCommands();
  }
  if (response.status === 200) {
    render(response.body.status, 0);
    // A reset says what it cleared and what stands and why: never "done" over a standing alarm.
    const reset = response.body.reset;
    if (reset) say(reset.text, Object.keys(reset.standing).length ? "error" : "ok");
    else say(`${what}: done`, "ok");
    return response;
  }
  if (response.status === 401) {
    session = { ...session, logged_in: false, csrf: null };
    updateSessionView();
  }
  say(response.body.error || `${what}: failed (HTTP ${response.status})`, "error");
  return response;
}

const MAX_PROGRAM_BYTES = 60000; // the server takes 64 KiB of request, the file's JSON with it

async function startProgram() {
  const file = $("program-file").files[0];
  const problems = $("program-problems");
  problems.hidden = true;
  if (file && file.size > MAX_PROGRAM_BYTES) {
    say(`${file.name} is ${file.size} bytes: a program file is at most ${MAX_PROGRAM_BYTES}`,
        "error");
    return;
  }
  const yaml = file ? await file.text() : $("program-yaml").value;
  const command = { yaml, filename: file ? file.name : "pasted.yaml",
                    ready_by: $("program-ready-by").value || null };
  const response = await send(command, "program start", "/api/program", $("program-start"));
  if (response.status === 200) {
    $("program-file").value = "";
  } else if (response.body.problems) {
    problems.textContent = response.body.problems.join("\n");
    problems.hidden = false;
  }
}

const MAX_RECIPE_BYTES = 380000; // the server takes 512 KiB of request, base64's third more

// The program a BeerXML recipe makes, by `hermsd program import`'s own code on the server,
// put in the program's text box to be read and started as any program; nothing is sent to
// the daemon. A file goes as its bytes, so its own declared encoding holds.
async function importRecipe() {
  const file = $("recipe-file").files[0];
  if (file && file.size > MAX_RECIPE_BYTES) {
    say(`${file.name} is ${file.size} bytes: export the one recipe (at most ${MAX_RECIPE_BYTES})`,
        "error");
    return;
  }
  const body = { filename: file ? file.name : "pasted.xml",
                 recipe: $("recipe-name").value.trim() || null };
  if (file) body.data = await base64Of(file);
  else body.xml = $("recipe-xml").value;
  say("making the program…");
  const response = await api("/api/program/import", body);
  if (response.status !== 200) {
    if (response.status === 401) {
      session = { ...session, logged_in: false, csrf: null };
      updateSessionView();
    }
    say(response.body.error || `import: failed (HTTP ${response.status})`, "error");
    return;
  }
  $("program-file").value = "";
  $("program-yaml").value = response.body.yaml;
  $("program-problems").hidden = true;
  say(`${response.body.name}: ${response.body.steps} steps, below: read them, then Start program`,
      "ok");
  $("program-yaml").scrollIntoView({ block: "center" });
}

function base64Of(file) {
  return new Promise((resolve, reject) => {
    const reader = new FileReader();
    reader.onload = () => resolve(String(reader.result).split(",", 2)[1] || "");
    reader.onerror = () => reject(reader.error);
    reader.readAsDataURL(file);
  });
}

function number(input, name, unit) {
  const text = input.value.trim();
  const value = Number(text);
  if (text === "" || !Number.isFinite(value)) {
    say(`${name}: enter a number in ${unit}`, "error");
    return null;
  }
  return value;
}

function wire() {
  $("sound").addEventListener("click", toggleSound);
  $("login-form").addEventListener("submit", async (event) => {
    event.preventDefault();
    const response = await api("/api/login", { password: $("password").value });
    $("password").value = "";
    if (response.status !== 200) {
      say(response.body.error || `login failed (HTTP ${response.status})`, "error");
      return;
    }
    session = response.body;
    updateSessionView();
    say("Logged in.", "ok");
    loadView();
  });
  $("logout").addEventListener("click", async () => {
    await api("/api/logout", {});
    session = { ...session, logged_in: false, csrf: null };
    updateSessionView();
    say("Logged out.");
    if (!session.view_open) window.location.reload();
  });
  $("setpoint-form").addEventListener("submit", (event) => {
    event.preventDefault();
    const value = number($("setpoint-input"), "setpoint", "°C");
    if (value !== null) send({ cmd: "set", setpoint: value }, `setpoint ${value} °C`);
  });
  $("mode-form").addEventListener("submit", (event) => {
    event.preventDefault();
    const mode = $("mode-select").value;
    const command = { cmd: "set", mode };
    if (mode === "manual" && $("output-input").value.trim() !== "") {
      const output = number($("output-input"), "output", "%");
      if (output === null) return;
      command.output = output;
    }
    send(command, `mode ${mode}`);
  });
  $("recipe-import-button").addEventListener("click", importRecipe);
  $("recipe-name").addEventListener("keydown", (event) => {
    if (event.key !== "Enter") return;
    event.preventDefault(); // the recipe's name, not the program's start
    importRecipe();
  });
  $("program-form").addEventListener("submit", (event) => {
    event.preventDefault();
    startProgram();
  });
  // The state the page shows, asked for outright: sent twice, it changes nothing more.
  $("pump-button").addEventListener("click", () => {
    const on = !shownPump;
    send({ cmd: "set", pump: on }, `pump ${on ? "on" : "off"}`, "/api/command",
         $("pump-button"));
  });
  // Only the alarms on the page: one raised since stays, for the brewer to read first.
  $("reset-alarm").addEventListener("click", () =>
    send({ cmd: "reset-alarm", kinds: shownAlarms }, "reset alarm"));
  // Confirm and next name the step shown: the daemon refuses them once another is current.
  $("program-confirm").addEventListener("click", () =>
    send({ cmd: "confirm", step: shownStep }, "confirm", "/api/command", $("program-confirm")));
  for (const [id, action] of [["program-next-button", "next"], ["program-pause", "pause"],
                              ["program-resume", "resume"], ["program-stop", "stop"]]) {
    $(id).addEventListener("click", () => {
      if (action === "stop" && !window.confirm("Stop the program?")) return;
      const command = action === "next" ? { cmd: "program", action, step: shownStep }
        : { cmd: "program", action };
      send(command, `program ${action}`, "/api/command", $(id));
    });
  }
  for (const button of document.querySelectorAll(".ranges button")) {
    button.addEventListener("click", () => {
      rangeHours = Number(button.dataset.hours);
      for (const other of document.querySelectorAll(".ranges button")) {
        other.classList.toggle("active", other === button);
      }
      if (chart) chart.setData(columns());
    });
  }
}

async function start() {
  wire();
  const response = await api("/api/session");
  session = response.body;
  updateSessionView();
  if (session.view_open || session.logged_in) {
    await loadView();
  } else {
    say("Log in to see the tun.");
  }
}

window.hermsd = {
  points: () => T.length,
  chart: () => chart,
  attention: () => ({ alerting: alertTimer !== null, beeps, sound: soundOn,
                      awake: typeof wakeLock === "object" && wakeLock !== null }),
};
setInterval(showFreshness, 1000);
start();
