"use strict";
// The live page: polls /api/state every second; pictures are reloaded only when the step count changes.
const MMHG = 133.322387415;
let shownSteps = -1, shownCameras = "", shownStrain = null;

function text(id, value) { document.getElementById(id).textContent = value; }

function fmt(v, digits) { return v === null || v === undefined ? "–" : Number(v).toPrecision(digits); }

function plot(id, series, scale, steps) {
  const c = document.getElementById(id), g = c.getContext("2d");
  g.clearRect(0, 0, c.width, c.height);
  const t = series.t, v = series.v.map(x => x === null ? null : x / scale);
  const pts = t.map((x, i) => [x, v[i]]).filter(p => p[0] !== null && p[1] !== null);
  if (pts.length < 2) { g.fillText("no readings yet", 10, 20); return; }
  let x0 = Math.min(...pts.map(p => p[0])), x1 = Math.max(...pts.map(p => p[0]));
  let y0 = Math.min(...pts.map(p => p[1])), y1 = Math.max(...pts.map(p => p[1]));
  if (x1 === x0) x1 = x0 + 1;
  if (y1 === y0) { y0 -= 1; y1 += 1; }
  const L = 45, B = 20, W = c.width - L - 5, H = c.height - B - 5;
  const X = x => L + (x - x0) / (x1 - x0) * W, Y = y => 5 + H - (y - y0) / (y1 - y0) * H;
  g.strokeStyle = "#999"; g.strokeRect(L, 5, W, H);
  g.fillStyle = "#444";
  g.fillText(y1.toPrecision(3), 2, 12); g.fillText(y0.toPrecision(3), 2, 5 + H);
  g.fillText(x0.toFixed(0), L, c.height - 5); g.fillText(x1.toFixed(0), L + W - 25, c.height - 5);
  g.strokeStyle = "#1565c0"; g.beginPath();
  pts.forEach((p, i) => (i ? g.lineTo(X(p[0]), Y(p[1])) : g.moveTo(X(p[0]), Y(p[1]))));
  g.stroke();
  g.fillStyle = "#d84315";
  steps.t.forEach((x, i) => {
    const y = steps.v[i];
    if (x !== null && y !== null) g.fillRect(X(x) - 2, Y(y / scale) - 2, 4, 4);
  });
}

function cameras(names, nSteps) {
  const box = document.getElementById("cameras");
  if (names.join() !== shownCameras) {
    box.replaceChildren(...names.map((name, i) => {
      const fig = document.createElement("figure"), img = document.createElement("img");
      img.className = "cam"; img.id = "cam" + i; img.alt = name; img.hidden = true;
      const cap = document.createElement("figcaption"); cap.textContent = name;
      fig.append(img, cap); return fig;
    }));
    shownCameras = names.join();
  }
  if (nSteps > 0 && nSteps !== shownSteps) {
    names.forEach((name, i) => {
      const img = document.getElementById("cam" + i);
      img.src = "/api/camera/" + i + ".png?row=" + (nSteps - 1);
      img.hidden = false;
    });
  }
}

async function strain(key) {
  if (key === shownStrain) return;
  shownStrain = key;
  const r = await fetch("/api/strain.png");
  const img = document.getElementById("strain");
  if (r.status === 200) {
    const old = img.src;
    img.src = URL.createObjectURL(await r.blob());
    if (old.startsWith("blob:")) URL.revokeObjectURL(old);
    img.hidden = false; text("nostrain", "");
  }
}

function parameters(models) {
  const box = document.getElementById("parameters");
  if (!models || !models.length) return;
  const table = document.createElement("table");
  const head = table.insertRow();
  ["model", "parameter", "value", "95 % interval", "source"].forEach(h => {
    const th = document.createElement("th"); th.textContent = h; head.append(th);
  });
  models.forEach(m => m.parameters.forEach((p, i) => {
    const row = table.insertRow();
    [i ? "" : m.model, p.name + (p.unit ? " [" + p.unit + "]" : ""), fmt(p.value, 4),
     "[" + fmt(p.low, 3) + ", " + fmt(p.high, 3) + "]", i ? "" : m.source].forEach(v => {
      row.insertCell().textContent = v;
    });
  }));
  box.replaceChildren(table);
}

function render(s) {
  text("file", s.file);
  text("status", s.status);
  text("message", s.message || (s.live && s.live.message) || "");
  const planned = s.planned_steps || (s.live && s.live.n_planned) || s.n_steps || 1;
  const bar = document.getElementById("progress");
  bar.max = planned; bar.value = s.n_steps;
  text("steps", s.n_steps + " / " + planned + " steps captured");
  if (s.live && s.live.pressure !== null && s.live.pressure !== undefined) {
    text("readings", "now: " + fmt(s.live.pressure / MMHG, 4) + " mmHg · " + fmt(s.live.force, 4) + " N · "
         + (s.live.phase || ""));
  }
  if (s.series) {
    plot("pressure", s.series.pressure, MMHG, {t: s.steps.t, v: s.steps.pressure});
    plot("force", s.series.force, 1, {t: s.steps.t, v: s.steps.force});
  }
  cameras(s.cameras || [], s.n_steps);
  shownSteps = s.n_steps;
  parameters(s.parameters);
  const ev = document.getElementById("events");
  ev.replaceChildren(...(s.events || []).map(e => {
    const li = document.createElement("li"); li.textContent = e.kind + ": " + e.message; return li;
  }));
  document.body.dataset.steps = String(s.n_steps);
  return strain(String(s.n_steps) + "/" + (s.live ? s.live.steps_reconstructed : "") + "/" +
                (s.parameters || []).map(m => m.source).join());
}

async function poll() {
  try {
    const r = await fetch("/api/state", {cache: "no-store"});
    if (r.ok) await render(await r.json());
    else text("status", "server answered " + r.status);
  } catch (e) {
    text("status", "server not reachable (the run has ended?)");
  }
  setTimeout(poll, 1000);
}

poll();
