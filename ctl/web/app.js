// foc-ctl dashboard: live telemetry (uPlot), status and faults, a console
// for foc-ctl commands and the setup wizard. Talks to foc-ctl's own HTTP
// server only (see ctl/src/dashboard/mod.rs for the API).
"use strict";

const WINDOW_S = 10;          // seconds of telemetry on the plot
const POLL_MS = 50;           // sample polling
const STATUS_MS = 300;        // status polling

// What the page has done, for people and for the browser test.
const dash = {
  plotted: 0,        // samples added to the plot
  frames: 0,         // plot redraws
  next: 0,           // next sample index to ask for
  t: [],             // device time [s]
  cols: {},          // signal -> values
  units: {},         // signal -> unit
  selected: new Set(["velocity", "iq"]),
  status: null,
  plot: null,
  dirty: false,
};
window.dash = dash;

const $ = (id) => document.getElementById(id);

async function getJson(url) {
  const r = await fetch(url, { cache: "no-store" });
  return r.json();
}

async function post(url, body) {
  const r = await fetch(url, { method: "POST", body: body === undefined ? "" : String(body) });
  return r.json();
}

// ---------------------------------------------------------------- plot

function makePlot() {
  if (dash.plot) { dash.plot.destroy(); dash.plot = null; }
  const names = [...dash.selected];
  const colors = ["#1f77b4", "#d62728", "#2ca02c", "#ff7f0e", "#9467bd", "#8c564b", "#e377c2", "#17becf"];
  const series = [{ label: "time [s]" }].concat(names.map((n, k) => ({
    label: `${n} [${dash.units[n] || ""}]`,
    stroke: colors[k % colors.length],
    width: 1.5,
    points: { show: false },
  })));
  const el = $("plot");
  dash.plot = new uPlot({
    width: Math.max(560, el.clientWidth - 8),
    height: 320,
    series,
    scales: { x: { time: false } },
    axes: [{ label: "device time [s]" }, {}],
  }, plotData(), el);
}

function plotData() {
  return [dash.t].concat([...dash.selected].map((n) => dash.cols[n] || []));
}

function redraw() {
  if (dash.dirty && dash.plot) {
    dash.plot.setData(plotData());
    dash.frames += 1;
    dash.dirty = false;
  }
  requestAnimationFrame(redraw);
}

async function pollSamples() {
  try {
    const s = await getJson(`/api/samples?since=${dash.next}`);
    if (s && s.t && s.t.length) {
      dash.next = s.next;
      dash.t.push(...s.t);
      for (const name of Object.keys(s.data)) {
        if (!dash.cols[name]) dash.cols[name] = [];
        dash.cols[name].push(...s.data[name]);
      }
      dash.plotted += s.t.length;
      // Keep the window.
      const tEnd = dash.t[dash.t.length - 1];
      let cut = 0;
      while (cut < dash.t.length && dash.t[cut] < tEnd - WINDOW_S) cut++;
      if (cut > 0) {
        dash.t.splice(0, cut);
        for (const name of Object.keys(dash.cols)) dash.cols[name].splice(0, cut);
      }
      dash.dirty = true;
    }
    if (s) {
      const given = s.every_periods > 0 ? `every ${s.every_periods} periods` : "not streaming";
      $("rate-info").textContent = `asked ${s.rate_hz} Hz, the drive streams ${given}; ${dash.plotted} samples plotted, ${s.lost} lost`;
    }
  } catch (e) {
    $("link").textContent = "link: no answer from foc-ctl";
  }
  setTimeout(pollSamples, POLL_MS);
}

async function setupSignals() {
  const sigs = await getJson("/api/signals");
  const box = $("signals");
  for (const s of sigs) {
    dash.units[s.name] = s.unit;
    const l = document.createElement("label");
    const c = document.createElement("input");
    c.type = "checkbox";
    c.value = s.name;
    c.checked = dash.selected.has(s.name);
    c.addEventListener("change", () => {
      if (c.checked) dash.selected.add(s.name); else dash.selected.delete(s.name);
      makePlot();
    });
    l.append(c, ` ${s.name} [${s.unit}]`);
    box.append(l);
  }
  makePlot();
  $("rate").addEventListener("change", async () => {
    const r = await post("/api/rate", $("rate").value);
    if (!r.ok) consoleLog(`rate ${$("rate").value} Hz`, r.error, false);
  });
}

// ---------------------------------------------------------------- status

const fmt = (x, d = 3) => (x === null || x === undefined) ? "?" : Number(x).toFixed(d);

function renderStatus(s) {
  dash.status = s;
  $("link").textContent = s.connected ? "link: connected" : "link: no answer from the drive";
  $("mode").textContent = s.mode || "?";
  $("calibrated").textContent = s.calibrated === null ? "?" : (s.calibrated ? "yes" : "no");
  $("bus").textContent = fmt(s.bus, 2);
  $("velocity").textContent = fmt(s.velocity, 3);
  $("position").textContent = fmt(s.position, 4);
  const p = s.calibration;
  $("progress").textContent = p
    ? (p.running ? `calibration running: ${p.step_name}` : `last calibration: ${p.result_text}${p.advice ? " (" + p.advice + ")" : ""}`)
    : "";
  const f = $("faults");
  f.innerHTML = "";
  const latched = (s.faults && s.faults.latched) || [];
  if (!latched.length) {
    f.textContent = "no faults";
  }
  for (const x of latched) {
    const d = document.createElement("div");
    d.className = "fault";
    d.innerHTML = "<b></b><div class='when'></div><div class='todo'></div>";
    d.querySelector("b").textContent = `${x.name} (${x.code})${s.faults.first === x.code ? ", the first" : ""}`;
    d.querySelector(".when").textContent = `trips when: ${x.trips_when || "?"}`;
    d.querySelector(".todo").textContent = `what to do: ${x.what_to_do || "?"}`;
    f.append(d);
  }
}

async function pollStatus() {
  try {
    const s = await getJson("/api/status");
    if (s) renderStatus(s);
  } catch (e) { /* shown by the samples' poll */ }
  setTimeout(pollStatus, STATUS_MS);
}

// ---------------------------------------------------------------- console

function consoleLog(cmd, text, ok) {
  const out = $("console-out");
  const c = document.createElement("div");
  c.className = "cmd";
  c.textContent = `$ foc-ctl ${cmd}`;
  const t = document.createElement("div");
  if (!ok) t.className = "refused";
  t.textContent = text;
  out.append(c, t);
  out.scrollTop = out.scrollHeight;
}

async function runCommand(line) {
  const r = await post("/api/console", line);
  consoleLog(line, r.output || r.error || "", r.ok);
  return r;
}

// ---------------------------------------------------------------- wizard

function step(id, state, text) {
  const li = $(`step-${id}`);
  const s = li.querySelector(".state");
  s.textContent = state;
  s.className = `state ${state}`;
  if (text !== undefined) li.querySelector(".result").textContent = text;
}

const sleep = (ms) => new Promise((r) => setTimeout(r, ms));

// Start a calibration and follow it in the status until it ends.
async function calibration(id, routine, limitS) {
  step(id, "running", "starting");
  const r = await post("/api/calibrate", routine);
  if (!r.ok) { step(id, "failed", r.error); return false; }
  const t0 = performance.now();
  let seen = false;
  for (;;) {
    await sleep(200);
    const s = await getJson("/api/status");
    renderStatus(s);
    const p = s.calibration;
    const t = (performance.now() - t0) / 1000;
    if (p && p.running) {
      seen = true;
      step(id, "running", `${t.toFixed(1)} s: ${p.step_name}`);
    } else if (p && (seen || t > 1.5)) {
      if (p.done) return true;
      step(id, "failed", `${p.result_text} (at ${p.step_name}): ${p.advice}`);
      return false;
    }
    if (t > limitS) { step(id, "failed", `not finished within ${limitS} s`); return false; }
  }
}

async function runWizard() {
  $("wizard-run").disabled = true;
  $("wizard-done").textContent = "";
  for (const id of ["motor", "offsets", "sensor", "identification", "tuning", "save"]) step(id, "pending", "");
  const ok = await wizardSteps();
  $("wizard-done").textContent = ok ? "setup complete: the drive is identified, tuned and saved" : "the wizard stopped: see the failed step";
  $("wizard-run").disabled = false;
}

async function wizardSteps() {
  // 1. The motor: a motor file or nameplate values, applied as one record
  // (the drive's own values kept when both are empty).
  step("motor", "running");
  const values = {};
  for (const inp of document.querySelectorAll("#step-motor .nameplate input")) {
    if (inp.value.trim()) values[inp.dataset.key] = inp.value.trim();
  }
  const mr = await post("/api/motor", JSON.stringify({ file: $("motor-file").value, values }));
  if (!mr.ok) { step("motor", "failed", mr.error); return false; }
  const m = await post("/api/console", "param all");
  const keep = m.output.split("\n").filter((l) => /^(pole-pairs|r |ld |lq |psi |board-max-current|max-current )/.test(l));
  step("motor", "done", `${mr.message}\n${keep.join("\n")}`);
  // 2. Offsets.
  if (!(await calibration("offsets", "offsets", 30))) return false;
  step("offsets", "done", "the current sensing's offsets are measured");
  // 3. Sensor check.
  step("sensor", "running", "turning the field slowly in open loop");
  const sc = await post("/api/sensor-check");
  if (!sc.pass) { step("sensor", "failed", sc.text); return false; }
  step("sensor", "done", sc.text);
  // 4. Identification.
  if (!(await calibration("identification", "identification", 300))) return false;
  const vals = [];
  for (const p of ["r", "ld", "lq", "psi", "current-kp", "speed-kp"]) {
    const r = await post("/api/console", `param ${p}`);
    vals.push(r.output.trim());
  }
  step("identification", "done", vals.join("\n"));
  // 5. Tuning report.
  step("tuning", "running", "a current step, captured by the scope");
  const t = await post("/api/tune");
  if (!t.ok) { step("tuning", "failed", t.report); return false; }
  step("tuning", "done", t.report);
  // 6. Save.
  step("save", "running");
  const sv = await runCommand("config save");
  if (!sv.ok) { step("save", "failed", sv.output); return false; }
  step("save", "done", sv.output);
  return true;
}

// ---------------------------------------------------------------- scope

async function armScope() {
  const v = (id) => $(id).value.trim();
  const set = `scope set --signals ${v("scope-signals")} --every ${v("scope-every")} --samples ${v("scope-samples")} ` +
    `--pre ${v("scope-pre")} --trigger ${v("scope-trigger")} --trigger-signal ${v("scope-tsig")} --level ${v("scope-level")}`;
  const r = await runCommand(set);
  if (!r.ok) { $("scope-state").textContent = "refused: see the console"; return; }
  const a = await runCommand("scope arm");
  if (!a.ok) { $("scope-state").textContent = "refused: see the console"; return; }
  followScope();
}

async function followScope() {
  for (let k = 0; k < 600; k++) {
    const s = await getJson("/api/scope");
    if (!s.ok) { $("scope-state").textContent = s.error; return; }
    if (s.state === "Done") { plotScope(s); return; }
    $("scope-state").textContent = `${s.state}: waiting for the trigger (${s.trigger}), ${s.captured} samples`;
    await sleep(200);
  }
}

function plotScope(s) {
  dash.scope = s;
  dash.scopePoints = s.t.length;
  $("scope-state").textContent = `captured ${s.t.length} samples every ${(s.sample_period_s * 1e6).toFixed(0)} us, the trigger at 0`;
  const el = $("scope-plot");
  el.innerHTML = "";
  const colors = ["#1f77b4", "#d62728", "#2ca02c", "#ff7f0e", "#9467bd", "#8c564b", "#e377c2", "#17becf"];
  const series = [{ label: "time [ms]" }].concat(s.channels.map((c, k) => ({
    label: c.name, stroke: colors[k % colors.length], width: 1.5, points: { show: false },
  })));
  const data = [s.t.map((x) => x * 1e3)].concat(s.channels.map((c) => c.values));
  dash.scopePlot = new uPlot({
    width: Math.max(560, el.clientWidth - 8), height: 260, series,
    scales: { x: { time: false } }, axes: [{ label: "time from the trigger [ms]" }, {}],
  }, data, el);
}

// ---------------------------------------------------------------- configuration

async function loadConfig() {
  const r = await getJson("/api/config");
  const box = $("config-tree");
  box.innerHTML = "";
  if (!r.ok) { $("config-msg").textContent = r.error; return; }
  const sections = new Map();
  for (const row of r.rows) {
    const sec = row.section || "(record)";
    if (!sections.has(sec)) sections.set(sec, []);
    sections.get(sec).push(row);
  }
  for (const [sec, rows] of sections) {
    const d = document.createElement("details");
    d.dataset.section = sec;
    if (sec === "(record)" || sec === "limits") d.open = true;
    const sm = document.createElement("summary");
    sm.textContent = sec;
    const t = document.createElement("table");
    for (const row of rows) {
      const tr = document.createElement("tr");
      tr.innerHTML = "<td class='key'></td><td><input></td><td class='unit'></td><td class='range'></td><td class='what'></td>";
      tr.querySelector(".key").textContent = row.key;
      const inp = tr.querySelector("input");
      inp.value = row.value;
      inp.dataset.key = row.key;
      inp.addEventListener("keydown", async (e) => {
        if (e.key !== "Enter") return;
        const res = await post("/api/config", JSON.stringify({ key: row.key, value: inp.value }));
        const m = $("config-msg");
        m.textContent = res.ok ? res.message : res.error;
        m.className = res.ok ? "" : "refused";
        if (res.ok) loadConfig(); else inp.value = row.value;
      });
      tr.querySelector(".unit").textContent = row.unit;
      tr.querySelector(".range").textContent = row.range;
      tr.querySelector(".what").textContent = row.what;
      t.append(tr);
    }
    d.append(sm, t);
    box.append(d);
  }
  dash.configRows = r.rows.length;
}

// ---------------------------------------------------------------- start

window.addEventListener("load", async () => {
  await setupSignals();
  requestAnimationFrame(redraw);
  pollSamples();
  pollStatus();
  $("console-form").addEventListener("submit", (e) => {
    e.preventDefault();
    const line = $("console-input").value.trim();
    if (line) runCommand(line);
  });
  $("clear-faults").addEventListener("click", () => runCommand("clear"));
  $("disable").addEventListener("click", async () => {
    const r = await post("/api/disable");
    consoleLog("(Disable button)", r.output || r.error || "", r.ok);
  });
  $("wizard-run").addEventListener("click", runWizard);
  $("scope-arm").addEventListener("click", armScope);
  $("scope-force").addEventListener("click", async () => { await runCommand("scope trigger"); });
  $("config-reload").addEventListener("click", loadConfig);
  loadConfig();
});
