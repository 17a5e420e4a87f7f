// stereod view: what one rig's daemon publishes, drawn live. Data arrive over the page's
// WebSocket (/ws) as JSON messages with a "type" (see stereod/view/server.py); the overlay
// image is fetched from /image/overlay.jpg when a new one is announced. Units: m, m/s, deg, s.
"use strict";

// The overlay's track colours (stereod/overlay.py's palette, as RGB), by track id.
const PALETTE = [
  "rgb(255,200,60)", "rgb(80,220,80)", "rgb(60,160,255)", "rgb(255,90,200)",
  "rgb(255,90,60)", "rgb(60,230,255)", "rgb(200,255,170)", "rgb(255,140,140)",
];
const ENDED_KEPT_S = 10;   // an ended track stays on the map this long (s of stream time)
const ARROW_S = 1.0;       // the map's velocity arrow spans this much motion (s)
const HISTORY = 600;       // states kept per track

const view = {
  tracks: new Map(),       // id -> {id, points: [state], endedAt: t or null}
  alive: null,             // the daemon's liveliness: true, false, or null (unknown)
  geometry: null,          // {hfov_deg, baseline_m, geometry}
  status: null,
  selected: null,          // the id the user chose, or null: the newest valid track
  lastT: null,             // newest stream time seen (s)
  dirty: true,
  drawn: [],               // [id, x, y] of each track's marker on the map (CSS px)
};

const $ = (id) => document.getElementById(id);
const colour = (id) => PALETTE[((id % PALETTE.length) + PALETTE.length) % PALETTE.length];
const fmt = (x, digits) => (x === null || x === undefined || !isFinite(x) ? "-" : x.toFixed(digits));

// ---------------------------------------------------------------- messages ----

function handle(msg) {
  switch (msg.type) {
    case "hello":
      view.tracks.clear();
      view.selected = null;
      $("rig").textContent = msg.rig;
      for (const [id, points] of Object.entries(msg.tracks)) {
        for (const p of points) addState(p);
        if (msg.ended.includes(Number(id))) endTrack(Number(id));
      }
      setAlive(msg.alive);
      view.geometry = msg.geometry;
      if (msg.status) setStatus(msg.status);
      if (msg.image) requestImage(msg.image);
      break;
    case "objects":
      for (const o of msg.objects) addState(o);
      view.lastT = Math.max(view.lastT ?? msg.t, msg.t);
      break;
    case "ended":
      endTrack(msg.track_id);
      break;
    case "alive":
      if (msg.alive && view.alive === false) {  // a new daemon: its track ids start again
        view.tracks.clear();
        view.selected = null;
        view.lastT = null;
      }
      setAlive(msg.alive);
      break;
    case "status":
      setStatus(msg.status);
      break;
    case "geometry":
      view.geometry = msg;
      break;
    case "image":
      requestImage(msg);
      break;
    default:
      break;
  }
  view.dirty = true;
}

function addState(o) {
  let track = view.tracks.get(o.id);
  if (!track) {
    track = { id: o.id, points: [], endedAt: null };
    view.tracks.set(o.id, track);
  }
  track.points.push(o);
  if (track.points.length > HISTORY) track.points.shift();
  view.lastT = Math.max(view.lastT ?? o.t, o.t);
}

function endTrack(id) {
  const track = view.tracks.get(id);
  if (track && track.endedAt === null) track.endedAt = view.lastT ?? 0;
}

function last(track) {
  return track.points[track.points.length - 1];
}

function setAlive(alive) {
  view.alive = alive;
  const el = $("daemon");
  el.textContent = alive === true ? "daemon: running" : alive === false ? "daemon: gone" : "daemon: unknown";
  el.className = "badge " + (alive === true ? "ok" : alive === false ? "bad" : "unknown");
}

// ------------------------------------------------------------------ status ----

function setStatus(s) {
  view.status = s;
  const st = $("state");
  st.textContent = s.state;
  st.className = "badge " + (s.state === "running" ? "ok" : s.state === "degraded" ? "bad" : "warn");
  const sum = (d) => Object.values(d || {}).reduce((a, b) => a + b, 0);
  const list = (d) => Object.entries(d || {}).map(([k, v]) => `${k} ${v}`).join(", ");
  const rows = [
    ["source", `${s.driver}: ${s.source}`],
    ["left eye", `${s.left.state}, ${fmt(s.left.fps, 1)} fps, ${s.left.frames} frames`],
    ["right eye", `${s.right.state}, ${fmt(s.right.fps, 1)} fps, ${s.right.frames} frames`],
    ["pairs", `${s.pairs} (${fmt(s.pairs_per_s, 1)} /s), queue ${s.queue_depth}`],
    ["skew", `mean ${fmt(s.skew_ms_mean, 1)} ms, max ${fmt(s.skew_ms_max, 1)} ms`],
    ["drops", sum(s.drops) ? `${sum(s.drops)}: ${list(s.drops)}` : "none"],
    ["errors", sum(s.errors) ? `${sum(s.errors)}: ${list(s.errors)}` : "none"],
    ["epipolar residual", s.epipolar_residual_px === null ? "-" : `${fmt(s.epipolar_residual_px, 2)} px`],
    ["geometry", s.geometry + (s.calibration_id ? ` (${s.calibration_id})` : "")],
  ];
  const body = $("status").tBodies[0];
  body.replaceChildren(...rows.map(([k, v]) => {
    const tr = document.createElement("tr");
    tr.dataset.key = k;
    const th = document.createElement("th");
    th.textContent = k;
    const td = document.createElement("td");
    td.textContent = v;
    tr.append(th, td);
    return tr;
  }));
  $("problems").replaceChildren(...(s.problems || []).slice(-5).map((p) => {
    const li = document.createElement("li");
    li.textContent = p;
    return li;
  }));
}

// ------------------------------------------------------------------- image ----

let imageBusy = false;
let imagePending = null;
let imageUrl = null;

async function requestImage(info) {
  if (imageBusy) {
    imagePending = info;
    return;
  }
  imageBusy = true;
  try {
    const r = await fetch(`/image/overlay.jpg?seq=${info.seq}`, { cache: "no-store" });
    if (r.ok) {
      const seq = r.headers.get("X-Stereod-Seq");
      const blob = await r.blob();
      const url = URL.createObjectURL(blob);
      const img = $("overlay");
      await new Promise((resolve) => {
        img.onload = resolve;
        img.onerror = resolve;
        img.src = url;
      });
      if (imageUrl) URL.revokeObjectURL(imageUrl);
      imageUrl = url;
      img.dataset.seq = seq;
      $("imagecaption").textContent =
        `pair ${seq}, t ${fmt(info.t, 3)} s, ${img.naturalWidth} x ${img.naturalHeight} px`;
    }
  } catch (err) {
    $("imagecaption").textContent = `image not loaded (${err})`;
  } finally {
    imageBusy = false;
    if (imagePending !== null) {
      const next = imagePending;
      imagePending = null;
      requestImage(next);
    }
  }
}

// -------------------------------------------------------------- track list ----

function visibleTracks() {
  const out = [];
  for (const t of view.tracks.values()) {
    if (t.endedAt !== null && view.lastT !== null && view.lastT - t.endedAt > ENDED_KEPT_S) continue;
    out.push(t);
  }
  return out.sort((a, b) => a.id - b.id);
}

function selectedTrack(tracks) {
  if (view.selected !== null) {
    const t = view.tracks.get(view.selected);
    if (t) return t;
  }
  let best = null;
  for (const t of tracks) {
    if (!t.points.some((p) => p.valid)) continue;
    if (best === null || (t.endedAt === null && best.endedAt !== null) ||
        ((t.endedAt === null) === (best.endedAt === null) && last(t).t > last(best).t)) best = t;
  }
  return best;
}

function renderList(tracks, chosen) {
  const body = $("tracks").tBodies[0];
  body.replaceChildren(...tracks.map((t) => {
    const o = last(t);
    const tr = document.createElement("tr");
    tr.dataset.trackId = t.id;
    tr.dataset.state = t.endedAt === null ? o.state : "ended";
    tr.dataset.valid = o.valid;
    if (o.valid) tr.dataset.speedMps = o.speed.toFixed(3);
    if (o.heading_valid) tr.dataset.headingDeg = o.heading.toFixed(2);
    if (chosen && chosen.id === t.id) tr.classList.add("selected");
    if (t.endedAt !== null) tr.classList.add("ended");
    const sw = `<span class="swatch" style="background:${colour(t.id)}"></span>`;
    const cells = [
      `${sw}#${t.id}`,
      t.endedAt === null ? o.state : "ended",
      o.p.map((x) => fmt(x, 2)).join(", "),
      o.valid ? `${fmt(o.speed, 2)} ± ${fmt(o.speed_sigma, 2)}` : "-",
      o.heading_valid ? `${fmt(o.heading, 1)} ± ${fmt(o.heading_sigma, 1)}` : "-",
    ];
    tr.innerHTML = cells.map((c) => `<td>${c}</td>`).join("");
    tr.addEventListener("click", () => { view.selected = t.id; view.dirty = true; });
    return tr;
  }));
  $("selected").textContent = chosen ? `#${chosen.id}` : "none";
}

// --------------------------------------------------------------------- map ----

function fitCanvas(canvas) {
  const ratio = window.devicePixelRatio || 1;
  const w = Math.max(canvas.clientWidth, 100);
  const h = Math.round(w * (canvas.height / canvas.width));
  if (canvas.width !== Math.round(w * ratio)) {
    canvas.style.height = `${h}px`;
    canvas.width = Math.round(w * ratio);
    canvas.height = Math.round(h * ratio);
  }
  const ctx = canvas.getContext("2d");
  ctx.setTransform(ratio, 0, 0, ratio, 0, 0);
  return { ctx, w: canvas.width / ratio, h: canvas.height / ratio };
}

function arrow(ctx, x0, y0, x1, y1) {
  const a = Math.atan2(y1 - y0, x1 - x0);
  const len = Math.hypot(x1 - x0, y1 - y0);
  if (len < 2) return;
  const head = Math.min(8, len / 2);
  ctx.beginPath();
  ctx.moveTo(x0, y0);
  ctx.lineTo(x1, y1);
  ctx.lineTo(x1 - head * Math.cos(a - 0.4), y1 - head * Math.sin(a - 0.4));
  ctx.moveTo(x1, y1);
  ctx.lineTo(x1 - head * Math.cos(a + 0.4), y1 - head * Math.sin(a + 0.4));
  ctx.stroke();
}

function drawMap(tracks) {
  const { ctx, w, h } = fitCanvas($("map"));
  ctx.clearRect(0, 0, w, h);
  const half = Math.tan(((view.geometry ? view.geometry.hfov_deg : 60) / 2) * Math.PI / 180);
  let zMax = 3;
  let xMax = 0.5;
  for (const t of tracks) {
    for (const p of t.points) {
      if (p.p[2] !== null) zMax = Math.max(zMax, p.p[2] + 0.5);
      if (p.p[0] !== null) xMax = Math.max(xMax, Math.abs(p.p[0]) + 0.3);
    }
  }
  zMax = Math.min(zMax, 30);
  xMax = Math.min(Math.max(xMax, zMax * half), 30);
  const pad = 24;
  const scale = Math.min((w - 2 * pad) / (2 * xMax), (h - 2 * pad) / zMax);
  const X = (x) => w / 2 + x * scale;
  const Z = (z) => h - pad - z * scale;
  // Grid, every 0.5 m (1 m when large), with labels.
  const step = zMax > 8 ? 2 : zMax > 4 ? 1 : 0.5;
  ctx.font = "11px system-ui, sans-serif";
  ctx.lineWidth = 1;
  ctx.strokeStyle = "#242830";
  ctx.fillStyle = "#6b7380";
  for (let z = 0; z <= zMax + 1e-9; z += step) {
    ctx.beginPath(); ctx.moveTo(0, Z(z)); ctx.lineTo(w, Z(z)); ctx.stroke();
    ctx.fillText(`${z} m`, 4, Z(z) - 3);
  }
  for (let x = -Math.floor(xMax / step) * step; x <= xMax + 1e-9; x += step) {
    ctx.beginPath(); ctx.moveTo(X(x), 0); ctx.lineTo(X(x), h); ctx.stroke();
    if (Math.abs(x) > 1e-9) ctx.fillText(`${x}`, X(x) + 2, h - 4);
  }
  ctx.fillText("X (m) \u2192", w - 62, h - 4);
  // Field of view wedge from the camera at the origin.
  const zw = zMax;
  ctx.fillStyle = "rgba(120,150,200,0.10)";
  ctx.strokeStyle = "rgba(120,150,200,0.55)";
  ctx.beginPath();
  ctx.moveTo(X(0), Z(0));
  ctx.lineTo(X(-zw * half), Z(zw));
  ctx.lineTo(X(zw * half), Z(zw));
  ctx.closePath();
  ctx.fill();
  ctx.stroke();
  const b = view.geometry ? view.geometry.baseline_m : 0.06;
  ctx.fillStyle = "#c8ccd4";
  ctx.fillRect(X(-b / 2) - 3, Z(0) - 3, Math.max(b * scale, 1) + 6, 6);
  // Trails, positions, velocity arrows and ids.
  view.drawn = [];
  for (const t of tracks) {
    const col = colour(t.id);
    const o = last(t);
    ctx.globalAlpha = t.endedAt === null ? 1 : 0.35;
    ctx.strokeStyle = col;
    ctx.fillStyle = col;
    ctx.lineWidth = 1.5;
    ctx.beginPath();
    let first = true;
    for (const p of t.points) {
      if (p.p[0] === null || p.p[2] === null) continue;
      if (first) ctx.moveTo(X(p.p[0]), Z(p.p[2])); else ctx.lineTo(X(p.p[0]), Z(p.p[2]));
      first = false;
    }
    ctx.stroke();
    if (o.p[0] === null || o.p[2] === null) continue;
    const cx = X(o.p[0]);
    const cy = Z(o.p[2]);
    view.drawn.push([t.id, cx, cy]);
    ctx.beginPath();
    ctx.arc(cx, cy, o.state === "tentative" ? 3 : 5, 0, 2 * Math.PI);
    const seen = o.state === "confirmed" || o.state === "stationary";
    if (seen && t.endedAt === null) ctx.fill(); else ctx.stroke();
    if (o.valid && o.v[0] !== null && o.v[2] !== null) {
      ctx.lineWidth = 2;
      arrow(ctx, cx, cy, X(o.p[0] + o.v[0] * ARROW_S), Z(o.p[2] + o.v[2] * ARROW_S));
    }
    ctx.font = "12px system-ui, sans-serif";
    ctx.fillText(`#${t.id}`, cx + 7, cy - 7);
  }
  ctx.globalAlpha = 1;
}

// -------------------------------------------------------------------- plot ----

function unwrap(values) {
  const out = [];
  let offset = 0;
  for (let i = 0; i < values.length; i++) {
    if (i > 0) {
      const d = values[i] + offset - out[i - 1];
      if (d > 180) offset -= 360; else if (d < -180) offset += 360;
    }
    out.push(values[i] + offset);
  }
  return out;
}

function panel(ctx, box, series, label, unit) {
  // series: {t: [], y: [], lo: [], hi: [], raw: [[t, y]]}, colour
  const { x0, y0, w, h } = box;
  ctx.strokeStyle = "#2c3038";
  ctx.strokeRect(x0, y0, w, h);
  ctx.fillStyle = "#8a93a0";
  ctx.font = "11px system-ui, sans-serif";
  ctx.fillText(`${label} (${unit})`, x0 + 4, y0 + 12);
  if (series.t.length === 0) {
    ctx.fillText("no valid velocity yet", x0 + w / 2 - 50, y0 + h / 2);
    return;
  }
  const t0 = series.t[0];
  const t1 = Math.max(series.t[series.t.length - 1], t0 + 1);
  let lo = Infinity;
  let hi = -Infinity;
  for (let i = 0; i < series.t.length; i++) {
    lo = Math.min(lo, series.lo[i], series.y[i]);
    hi = Math.max(hi, series.hi[i], series.y[i]);
  }
  for (const [, y] of series.raw) { lo = Math.min(lo, y); hi = Math.max(hi, y); }
  const span = Math.max(hi - lo, series.minSpan);
  const mid = (hi + lo) / 2;
  lo = mid - span * 0.6;
  hi = mid + span * 0.6;
  const X = (t) => x0 + 40 + ((t - t0) / (t1 - t0)) * (w - 48);
  const Y = (y) => y0 + h - 6 - ((y - lo) / (hi - lo)) * (h - 22);
  ctx.fillStyle = "#6b7380";
  for (const v of [lo + span * 0.1, mid, hi - span * 0.1]) {
    ctx.fillText(v.toFixed(Math.abs(span) < 1 ? 2 : 0), x0 + 2, Y(v) + 4);
  }
  ctx.fillText(`${(t1 - t0).toFixed(1)} s`, x0 + w - 40, y0 + h - 8);
  ctx.fillStyle = series.band;
  ctx.beginPath();
  series.t.forEach((t, i) => (i ? ctx.lineTo(X(t), Y(series.hi[i])) : ctx.moveTo(X(t), Y(series.hi[i]))));
  for (let i = series.t.length - 1; i >= 0; i--) ctx.lineTo(X(series.t[i]), Y(series.lo[i]));
  ctx.closePath();
  ctx.fill();
  ctx.strokeStyle = series.colour;
  ctx.lineWidth = 1.5;
  ctx.beginPath();
  series.t.forEach((t, i) => (i ? ctx.lineTo(X(t), Y(series.y[i])) : ctx.moveTo(X(t), Y(series.y[i]))));
  ctx.stroke();
  ctx.fillStyle = "#e4e6ea";
  for (const [t, y] of series.raw) ctx.fillRect(X(t) - 1.5, Y(y) - 1.5, 3, 3);
}

function drawPlot(track) {
  const { ctx, w, h } = fitCanvas($("plot"));
  ctx.clearRect(0, 0, w, h);
  const pts = track ? track.points.filter((p) => p.valid && p.speed !== null && p.heading !== null) : [];
  const col = track ? colour(track.id) : "#888";
  const band = col.replace("rgb(", "rgba(").replace(")", ",0.22)");
  const t = pts.map((p) => p.t);
  const speed = pts.map((p) => p.speed);
  const ssig = pts.map((p) => p.speed_sigma ?? 0);
  const hpts = pts.filter((p) => p.heading_valid);  // the speed can be known before the heading
  const ht = hpts.map((p) => p.t);
  const heading = unwrap(hpts.map((p) => p.heading));
  const hsig = hpts.map((p) => Math.min(p.heading_sigma ?? 0, 90));
  const raw = pts.filter((p) => p.raw && p.raw[0] !== null && p.raw[2] !== null);
  const rawSpeed = raw.map((p) => [p.t, Math.hypot(p.raw[0], p.raw[1] ?? 0, p.raw[2])]);
  const rawHeading = raw.map((p) => {
    let a = (Math.atan2(p.raw[0], p.raw[2]) * 180) / Math.PI;
    const ref = heading[hpts.indexOf(p)] ?? heading[heading.length - 1] ?? a;
    while (a - ref > 180) a -= 360;
    while (a - ref < -180) a += 360;
    return [p.t, a];
  });
  const gap = 8;
  const ph = (h - gap) / 2;
  panel(ctx, { x0: 0, y0: 0, w, h: ph }, {
    t, y: speed, lo: speed.map((s, i) => s - ssig[i]), hi: speed.map((s, i) => s + ssig[i]),
    raw: rawSpeed, colour: col, band, minSpan: 0.2,
  }, "speed", "m/s");
  panel(ctx, { x0: 0, y0: ph + gap, w, h: ph }, {
    t: ht, y: heading, lo: heading.map((s, i) => s - hsig[i]), hi: heading.map((s, i) => s + hsig[i]),
    raw: rawHeading, colour: col, band, minSpan: 20,
  }, "heading", "deg");
}

// ------------------------------------------------------------------- loop ----

function frame() {
  if (view.dirty) {
    view.dirty = false;
    const tracks = visibleTracks();
    const chosen = selectedTrack(tracks);
    renderList(tracks, chosen);
    drawMap(tracks);
    drawPlot(chosen);
  }
  window.requestAnimationFrame(frame);
}

function connect() {
  const server = $("server");
  const ws = new WebSocket(`${location.protocol === "https:" ? "wss" : "ws"}://${location.host}/ws`);
  ws.onopen = () => { server.textContent = "page: connected"; server.className = "badge ok"; };
  ws.onmessage = (e) => handle(JSON.parse(e.data));
  ws.onclose = () => {
    server.textContent = "page: reconnecting";
    server.className = "badge bad";
    window.setTimeout(connect, 1000);
  };
}

window.addEventListener("resize", () => { view.dirty = true; });
$("map").addEventListener("click", (e) => {
  // The nearest track within 20 px is selected; a click elsewhere goes back to the newest.
  const r = e.target.getBoundingClientRect();
  const x = e.clientX - r.left;
  const y = e.clientY - r.top;
  let best = null;
  let bestD = 20;
  for (const [id, cx, cy] of view.drawn) {
    const d = Math.hypot(cx - x, cy - y);
    if (d < bestD) { best = id; bestD = d; }
  }
  view.selected = best;
  view.dirty = true;
});
connect();
window.requestAnimationFrame(frame);
