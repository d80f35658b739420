// pdcov watch: draws the state pushed on /events (server-sent events) on a canvas.
// Coordinates are local ENU metres (east x, north y) about the mission origin.
"use strict";

const mapCanvas = document.getElementById("map");
const ctx = mapCanvas.getContext("2d");
let state = null;
const tileCache = new Map();

// A perceptual colour scale (viridis, 9 stops) for P_D in [0, 1].
const STOPS = [[68, 1, 84], [71, 44, 122], [59, 81, 139], [44, 113, 142], [33, 144, 141],
               [39, 173, 129], [92, 200, 99], [170, 220, 50], [253, 231, 37]];
function colour(p) {
  const s = Math.min(Math.max(p, 0), 1) * (STOPS.length - 1);
  const i = Math.min(Math.floor(s), STOPS.length - 2), f = s - i;
  return STOPS[i].map((a, k) => Math.round(a + f * (STOPS[i + 1][k] - a)));
}

function pct(share) {
  return share === null || share === undefined ? "-" : (100 * share).toFixed(1) + " %";
}

// The view: ENU extent of the grid (or domain) fitted into the canvas, north up.
function view() {
  let xs = [], ys = [];
  if (state.grid) {
    const g = state.grid;
    xs.push(g.x0_m, g.x0_m + g.w * g.cell_size_m);
    ys.push(g.y0_m, g.y0_m + g.h * g.cell_size_m);
  }
  if (state.domain) for (const [x, y] of state.domain.boundary) { xs.push(x); ys.push(y); }
  for (const v of state.vehicles) for (const [x, y] of v.track) { xs.push(x); ys.push(y); }
  if (!xs.length) { xs = [-50, 50]; ys = [-50, 50]; }
  const x0 = Math.min(...xs), x1 = Math.max(...xs), y0 = Math.min(...ys), y1 = Math.max(...ys);
  const pad = 0.05 * Math.max(x1 - x0, y1 - y0, 1);
  const W = mapCanvas.width, H = mapCanvas.height;
  const scale = Math.min(W / (x1 - x0 + 2 * pad), H / (y1 - y0 + 2 * pad));
  const cx = (x0 + x1) / 2, cy = (y0 + y1) / 2;
  return {scale, px: (x) => W / 2 + (x - cx) * scale, py: (y) => H / 2 - (y - cy) * scale};
}

function path(points, v) {
  ctx.beginPath();
  points.forEach(([x, y], i) => (i ? ctx.lineTo(v.px(x), v.py(y)) : ctx.moveTo(v.px(x), v.py(y))));
}

// Optional basemap: XYZ (web Mercator) tiles from the folder pdcov serves, placed in ENU by a
// local equirectangular approximation about the origin (good to centimetres over a few km).
function drawBasemap(v) {
  const b = state.basemap, o = state.origin;
  if (!b || !o || !b.zooms.length) return;
  const R = 6378137, lat0 = o.lat_deg * Math.PI / 180;
  const toEnu = (lat, lon) => [(lon - o.lon_deg) * Math.PI / 180 * R * Math.cos(lat0),
                               (lat - o.lat_deg) * Math.PI / 180 * R];
  const mpp = 1 / v.scale;  // metres per screen pixel
  let z = b.zooms[0];
  for (const zz of b.zooms) if (2 * Math.PI * R * Math.cos(lat0) / (256 * 2 ** zz) >= mpp / 1.5) z = zz;
  const n = 2 ** z;
  const tileX = (lon) => Math.floor((lon + 180) / 360 * n);
  const tileY = (lat) => { const r = lat * Math.PI / 180;
    return Math.floor((1 - Math.log(Math.tan(r) + 1 / Math.cos(r)) / Math.PI) / 2 * n); };
  const lonOf = (x) => x / n * 360 - 180;
  const latOf = (y) => Math.atan(Math.sinh(Math.PI * (1 - 2 * y / n))) * 180 / Math.PI;
  const W = mapCanvas.width, H = mapCanvas.height;
  const corner = (px, py) => {  // screen -> lat, lon
    const x = (px - v.px(0)) / v.scale, y = (v.py(0) - py) / v.scale;
    return [o.lat_deg + y / R * 180 / Math.PI, o.lon_deg + x / (R * Math.cos(lat0)) * 180 / Math.PI];
  };
  const [latN, lonW] = corner(0, 0), [latS, lonE] = corner(W, H);
  for (let tx = tileX(lonW); tx <= tileX(lonE); tx++) {
    for (let ty = tileY(latN); ty <= tileY(latS); ty++) {
      const url = `basemap/${z}/${tx}/${ty}.${b.ext}`;
      let img = tileCache.get(url);
      if (!img) { img = new Image(); img.onload = draw; img.src = url; tileCache.set(url, img); }
      if (!img.complete || !img.naturalWidth) continue;
      const [xa, ya] = toEnu(latOf(ty), lonOf(tx)), [xb, yb] = toEnu(latOf(ty + 1), lonOf(tx + 1));
      ctx.drawImage(img, v.px(xa), v.py(ya), v.px(xb) - v.px(xa), v.py(yb) - v.py(ya));
    }
  }
}

function drawGrid(v) {
  const g = state.grid;
  if (!g) return;
  const bytes = Uint8Array.from(atob(g.pd_b64), (c) => c.charCodeAt(0));
  const off = document.createElement("canvas");
  off.width = g.w; off.height = g.h;
  const octx = off.getContext("2d"), img = octx.createImageData(g.w, g.h);
  for (let r = 0; r < g.h; r++) {
    for (let c = 0; c < g.w; c++) {
      const q = bytes[r * g.w + c], k = 4 * ((g.h - 1 - r) * g.w + c);  // row 0 is south
      if (q === 255) { img.data.set([119, 119, 119, 200], k); continue; }
      const [R, G, B] = colour(q / 254);
      img.data.set([R, G, B, 215], k);
    }
  }
  octx.putImageData(img, 0, 0);
  ctx.imageSmoothingEnabled = false;
  const x1 = g.x0_m + g.w * g.cell_size_m, y1 = g.y0_m + g.h * g.cell_size_m;
  ctx.drawImage(off, v.px(g.x0_m), v.py(y1), v.px(x1) - v.px(g.x0_m), v.py(g.y0_m) - v.py(y1));
}

function draw() {
  if (!state) return;
  ctx.clearRect(0, 0, mapCanvas.width, mapCanvas.height);
  const v = view();
  drawBasemap(v);
  drawGrid(v);
  if (state.domain) {
    for (const ob of state.domain.obstacles) {
      path(ob, v); ctx.closePath(); ctx.fillStyle = "rgba(80,80,80,0.8)"; ctx.fill();
    }
    path(state.domain.boundary, v); ctx.closePath();
    ctx.lineWidth = 2; ctx.strokeStyle = "#111"; ctx.stroke();
    // What was drawn, for tests and the curious: the source and the outline in canvas pixels.
    mapCanvas.dataset.domainSource = state.domain.source;
    mapCanvas.dataset.domainPx = JSON.stringify(state.domain.boundary.map(([x, y]) => [v.px(x), v.py(y)]));
  } else {
    delete mapCanvas.dataset.domainSource;
    delete mapCanvas.dataset.domainPx;
  }
  for (const veh of state.vehicles) {
    ctx.strokeStyle = veh.color;
    if (veh.track.length > 1) { path(veh.track, v); ctx.lineWidth = 2; ctx.setLineDash([]); ctx.stroke(); }
    if (veh.footprint) {
      path(veh.footprint, v); ctx.closePath(); ctx.lineWidth = 2; ctx.setLineDash([6, 4]);
      ctx.stroke(); ctx.setLineDash([]);
    }
    if (veh.track.length) {
      const [x, y] = veh.track[veh.track.length - 1];
      ctx.beginPath(); ctx.arc(v.px(x), v.py(y), 5, 0, 2 * Math.PI);
      ctx.fillStyle = veh.color; ctx.fill();
      ctx.fillStyle = "#000"; ctx.font = "12px sans-serif"; ctx.fillText(veh.id, v.px(x) + 7, v.py(y) - 7);
    }
  }
  drawRefly(v);
  // scale bar
  const metres = [1, 2, 5, 10, 20, 50, 100, 200, 500, 1000, 2000, 5000].find((m) => m * v.scale > 60) || 10000;
  const y = mapCanvas.height - 12;
  ctx.strokeStyle = "#000"; ctx.lineWidth = 3; ctx.beginPath(); ctx.moveTo(12, y);
  ctx.lineTo(12 + metres * v.scale, y); ctx.stroke();
  ctx.fillStyle = "#000"; ctx.font = "12px sans-serif"; ctx.fillText(`${metres} m`, 16, y - 6);
}

// The re-fly proposed ([lat, lon] pairs), in ENU by the equirectangular approximation about
// the origin the basemap uses: its gap outlines and its path.
function drawRefly(v) {
  const r = state.refly, o = state.origin;
  if (!r || !o) return;
  const R = 6378137, lat0 = o.lat_deg * Math.PI / 180;
  const enu = (pts) => pts.map(([lat, lon]) => [(lon - o.lon_deg) * Math.PI / 180 * R * Math.cos(lat0),
                                               (lat - o.lat_deg) * Math.PI / 180 * R]);
  ctx.strokeStyle = "#d6008f"; ctx.lineWidth = 2;
  for (const ring of r.gaps) { path(enu(ring), v); ctx.closePath(); ctx.stroke(); }
  ctx.setLineDash([4, 3]); path(enu(r.waypoints), v); ctx.stroke(); ctx.setLineDash([]);
  mapCanvas.dataset.reflyId = r.id;
}

async function post(url, body) {
  const resp = await fetch(url, {method: "POST", headers: {"Content-Type": "application/json"},
                                 body: JSON.stringify(body), credentials: "same-origin"});
  const doc = await resp.json();
  if (!resp.ok) throw new Error(doc.error || resp.statusText);
  return doc;
}

function showRefly(lines, outcome) {
  document.getElementById("refly-lines").replaceChildren(...lines.map((text) => {
    const li = document.createElement("li"); li.textContent = text; return li;
  }));
  document.getElementById("refly-outcome").textContent = outcome || "";
}

document.getElementById("refly-form").addEventListener("submit", async (ev) => {
  ev.preventDefault();
  const target = document.getElementById("refly-target").value;
  const send = document.getElementById("refly-send");
  send.hidden = true;
  showRefly(["computing the re-fly ..."]);
  try {
    const p = await post("api/refly", {vehicle: document.getElementById("refly-vehicle").value,
                                       target_pd: target ? Number(target) : null});
    showRefly(p.lines);
    send.dataset.id = p.id; send.textContent = `Send mission ${p.id} to ${p.vehicle}`; send.hidden = false;
  } catch (err) { showRefly([], `no re-fly: ${err.message}`); }
});

document.getElementById("refly-send").addEventListener("click", async (ev) => {
  const send = ev.target;
  if (!window.confirm(`${send.textContent}? Its autopilot's mission is replaced; the pilot flies it.`)) return;
  send.hidden = true;
  document.getElementById("refly-outcome").textContent = "sending ...";
  try {
    const r = await post("api/refly/confirm", {id: send.dataset.id});
    document.getElementById("refly-outcome").textContent = r.line;
  } catch (err) { document.getElementById("refly-outcome").textContent = `not sent: ${err.message}`; }
});

function row(cells, cls) {
  const tr = document.createElement("tr");
  for (const [text, c] of cells) {
    const td = document.createElement("td"); td.textContent = text; if (c) td.className = c;
    tr.appendChild(td);
  }
  if (cls) tr.className = cls;
  return tr;
}

function showTables() {
  const f = state.fleet, target = f.target === null ? null : String(f.target);
  const fleet = document.getElementById("fleet");
  fleet.replaceChildren();
  for (const t of f.thresholds) {
    fleet.appendChild(row([[`P_D \u2265 ${t}`], [pct(f.proportion[String(t)]), String(t) === target ? "target" : ""]]));
  }
  fleet.appendChild(row([["mean P_D"], [f.mean_pd === null ? "-" : f.mean_pd.toFixed(3)]]));
  fleet.appendChild(row([["vehicles merged"], [f.merged.join(", ") || "-"]]));
  const veh = document.getElementById("vehicles");
  veh.replaceChildren(row([["id"], [`\u2265 ${f.target ?? "-"}`], ["frames"], ["skipped"], ["link"], ["age"]]));
  for (const v of state.vehicles) {
    const tr = row([[v.id], [pct(v.proportion[target])], [v.frames_used ?? "-"], [v.frames_skipped ?? "-"],
                    [v.alive === false ? "GONE" : (v.link || "?"), v.alive === false ? "gone" : ""],
                    [v.age_s === null ? "-" : v.age_s.toFixed(1) + " s"]]);
    tr.firstChild.style.color = v.color;
    tr.dataset.vehicle = v.id;
    veh.appendChild(tr);
  }
}

function show(s) {
  state = s;
  const f = s.fleet, cov = document.getElementById("coverage");
  const share = f.target === null ? null : f.proportion[String(f.target)];
  cov.textContent = pct(share);
  cov.dataset.share = share === undefined || share === null ? "" : String(share);
  cov.dataset.version = String(s.version);
  cov.dataset.meanPd = f.mean_pd === null ? "" : String(f.mean_pd);
  document.getElementById("target").textContent = f.target ?? "-";
  document.getElementById("domain-source").textContent = s.domain ? s.domain.source : "not known";
  document.getElementById("domain-note").textContent = s.domain_note || "";
  const warnings = document.getElementById("warnings");
  warnings.replaceChildren(...(s.warnings || []).map((text) => {
    const li = document.createElement("li");
    li.textContent = text;
    return li;
  }));
  document.getElementById("status-line").textContent =
    `${s.vehicles.length} vehicle(s); update ${s.version}; ${new Date().toLocaleTimeString()}`;
  showTables();
  const sel = document.getElementById("refly-vehicle");
  const ids = s.vehicles.map((v) => v.id);
  if (sel.options.length !== ids.length || ids.some((id, i) => sel.options[i].value !== id)) {
    sel.replaceChildren(...ids.map((id) => new Option(id, id)));
  }
  document.getElementById("refly-ask").disabled = !s.refly_available || !ids.length;
  if (s.refly_outcome) document.getElementById("refly-outcome").textContent = s.refly_outcome;
  draw();
}

function colourBar() {
  const c = document.getElementById("colorbar"), cc = c.getContext("2d");
  for (let i = 0; i < c.width; i++) {
    const [R, G, B] = colour(i / (c.width - 1));
    cc.fillStyle = `rgb(${R},${G},${B})`; cc.fillRect(i, 0, 1, c.height);
  }
}

function fit() {
  mapCanvas.width = Math.max(320, Math.min(window.innerWidth - 440, 1000));
  mapCanvas.height = Math.max(240, Math.min(window.innerHeight - 120, 800));
  draw();
}

// The server answered this page's ?token= with its cookie: take the token out of the
// address bar, so that it is not left in screenshots, bookmarks or shared links.
const here = new URL(window.location.href);
if (here.searchParams.has("token")) {
  here.searchParams.delete("token");
  history.replaceState(null, "", here.pathname + here.search + here.hash);
}

colourBar();
window.addEventListener("resize", fit);
fit();
// An update that cannot be read or drawn is shown, never a silently frozen map: the
// banner says what failed and that the figures shown are those of the last good update.
function showError(what, err) {
  const el = document.getElementById("error");
  el.textContent = `${what}: ${err && err.message ? err.message : err}; the map shows the ` +
    `last update that could be read (${state ? "update " + state.version : "none yet"})`;
  el.hidden = false;
}

const events = new EventSource("events");
events.onmessage = (e) => {
  let s;
  try {
    s = JSON.parse(e.data);
  } catch (err) {
    showError("an update from pdcov watch could not be read", err);
    return;
  }
  if (s.build_error) {  // pdcov watch could not build this update: it resent the last one
    showError("pdcov watch could not build the map state", s.build_error);
  }
  const previous = state;
  try {
    show(s);
  } catch (err) {
    state = previous;
    showError("an update from pdcov watch could not be drawn", err);
    return;
  }
  if (!s.build_error) {
    document.getElementById("error").hidden = true;
  }
};
events.onerror = () => {
  // CLOSED: the server refused the stream (e.g. restarted with a new token); else retrying.
  document.getElementById("status-line").textContent = events.readyState === EventSource.CLOSED
    ? "not connected: reload, or open the address (with ?token=) pdcov watch printed"
    : "connection lost; retrying\u2026";
};
