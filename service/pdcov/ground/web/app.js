// pdcov watch: the state pushed on /events (server-sent events) drawn with Leaflet
// (vendor/leaflet, served by pdcov itself: nothing comes from the network). Every position
// in the state is [lat_deg, lon_deg] (WGS84); the heat map arrives already resampled onto
// web Mercator (service/pdcov/ground/map_layers.py) and is laid on its bounds as an image.
//
// For other parts of the page (docs/ground-station.md "Web map"): window.pdcov holds the
// Leaflet map, its layer groups, the element #pdcov-controls where operator actions go,
// state() (the last state drawn) and onUpdate(fn) (fn(state) after each state is drawn).
"use strict";

const PD_NOT_FREE = 254, PD_OFF_GRID = 255;
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

function fixed(x, digits) {
  return typeof x === "number" ? x.toFixed(digits) : "-";
}

let state = null;
const listeners = [];
const mapElement = document.getElementById("map");
const map = L.map(mapElement, {maxZoom: 24, zoomSnap: 0.25});
map.setView([0, 0], 2);
map.attributionControl.setPrefix("Leaflet");
L.control.scale({metric: true, imperial: false, maxWidth: 160}).addTo(map);
const outlineRenderer = L.canvas();  // the outline may hold thousands of edges

const LAYER_NAMES = {
  heat: "P_D heat map", outline: "outline at the target P_D", domain: "domain and obstacles",
  plans: "plan waypoints", tracks: "tracks", footprints: "footprints now",
  candidates: "detection candidates", gaps: "gaps to re-fly", refly: "re-fly path proposed"};
const layers = {};
const overlays = {};
for (const [key, name] of Object.entries(LAYER_NAMES)) {
  layers[key] = L.layerGroup().addTo(map);
  overlays[name] = layers[key];
}
const layerControl = L.control.layers(null, overlays, {collapsed: false}).addTo(map);

window.pdcov = Object.freeze({
  map, layers, layerControl,
  controls: document.getElementById("pdcov-controls"),
  state: () => state,
  onUpdate: (fn) => { listeners.push(fn); },
});

// Text only: names and classes come from the bus, never parsed as HTML.
function el(tag, text, cls) {
  const e = document.createElement(tag);
  if (text !== undefined) e.textContent = text;
  if (cls) e.className = cls;
  return e;
}

// -- the offline basemap (pdcov watch --basemap): asked of pdcov's /basemap/{z}/{x}/{y}.
let basemapLayer = null;
function showBasemap(b) {
  if (basemapLayer || !b || !b.zooms.length) return;
  // Shown from 3 levels below its coarsest tiles (scaled down: 64 tiles a tile at most),
  // up to 24 (its finest scaled up); hidden when zoomed out further.
  basemapLayer = L.tileLayer(`basemap/{z}/{x}/{y}.${b.ext}`, {
    minNativeZoom: b.zooms[0], maxNativeZoom: b.zooms[b.zooms.length - 1],
    minZoom: Math.max(0, b.zooms[0] - 3), maxZoom: 24,
    attribution: b.attribution ? el("span", b.attribution).innerHTML : ""});
  basemapLayer.addTo(map);
  layerControl.addOverlay(basemapLayer, `basemap (${b.name})`);
}

// -- the heat map: the state's P_D codes painted into an image of the page's own making.
let heatOverlay = null, heatKey = null, heatSeq = 0;
function showHeat(g) {
  if (!g) {
    layers.heat.clearLayers();
    heatOverlay = null; heatKey = null;
    return;
  }
  const key = g.pd_b64 + JSON.stringify(g.bounds_lat_lon);
  if (key === heatKey) return;
  heatKey = key;
  const bytes = Uint8Array.from(atob(g.pd_b64), (c) => c.charCodeAt(0));
  const canvas = document.createElement("canvas");
  canvas.width = g.w; canvas.height = g.h;
  const cx = canvas.getContext("2d"), img = cx.createImageData(g.w, g.h);
  for (let k = 0; k < bytes.length; k++) {  // rows from the north, as the image's
    const q = bytes[k];
    if (q === PD_OFF_GRID) continue;  // transparent
    const rgba = q === PD_NOT_FREE ? [119, 119, 119, 170] : [...colour(q / g.pd_levels), 215];
    img.data.set(rgba, 4 * k);
  }
  cx.putImageData(img, 0, 0);
  const seq = ++heatSeq;
  canvas.toBlob((blob) => {
    if (seq !== heatSeq) return;  // a newer heat map is on its way
    const url = URL.createObjectURL(blob);
    if (heatOverlay) {
      const old = heatOverlay.getElement().src;
      heatOverlay.once("load", () => URL.revokeObjectURL(old));
      heatOverlay.setUrl(url).setBounds(L.latLngBounds(g.bounds_lat_lon));
    } else {
      heatOverlay = L.imageOverlay(url, g.bounds_lat_lon, {className: "pd-layer"});
      layers.heat.addLayer(heatOverlay);
    }
    mapElement.dataset.heatVersion = String(state ? state.version : "");
  });
}

function showOutline(g) {
  layers.outline.clearLayers();
  if (!g || !g.outline_lat_lon || !g.outline_lat_lon.length) return;
  const opts = {renderer: outlineRenderer, interactive: false};
  layers.outline.addLayer(L.polyline(g.outline_lat_lon, {...opts, color: "#222", weight: 4}));
  layers.outline.addLayer(L.polyline(g.outline_lat_lon, {...opts, color: "#fff", weight: 2}));
}

function showDomain(d) {
  layers.domain.clearLayers();
  if (!d) {
    delete mapElement.dataset.domainSource;
    return;
  }
  for (const ob of d.obstacles_lat_lon) {
    layers.domain.addLayer(L.polygon(ob, {stroke: false, fillColor: "#505050",
                                          fillOpacity: 0.7, interactive: false}));
  }
  layers.domain.addLayer(L.polygon(d.boundary_lat_lon, {fill: false, color: "#111",
                                                        weight: 2, interactive: false}));
  mapElement.dataset.domainSource = d.source;
}

function showPlans(plans) {
  layers.plans.clearLayers();
  for (const p of plans || []) {
    layers.plans.addLayer(L.polyline(p.waypoints_lat_lon, {color: "#222", weight: 2,
                                                           dashArray: "6 4"}));
    p.waypoints_lat_lon.forEach((w, k) => layers.plans.addLayer(
      L.circleMarker(w, {radius: 4, color: "#222", weight: 1, fillColor: "#fff",
                         fillOpacity: 1})
        .bindTooltip(el("span", `waypoint ${k + 1} of ${p.source}`))));
  }
}

function showVehicles(vehicles) {
  layers.tracks.clearLayers();
  layers.footprints.clearLayers();
  for (const v of vehicles) {
    if (v.track_lat_lon.length > 1) {
      layers.tracks.addLayer(L.polyline(v.track_lat_lon, {color: v.color, weight: 2}));
    }
    if (v.track_lat_lon.length) {
      layers.tracks.addLayer(L.circleMarker(v.track_lat_lon[v.track_lat_lon.length - 1], {
        radius: 6, color: "#000", weight: 1, fillColor: v.color, fillOpacity: 1})
        .bindTooltip(el("span", v.id), {permanent: true, direction: "right"}));
    }
    if (v.footprint_lat_lon) {
      layers.footprints.addLayer(L.polygon(v.footprint_lat_lon, {
        color: v.color, weight: 2, dashArray: "6 4", fill: false, interactive: false}));
    }
  }
}

// -- detection candidates (pins): kept by uid (unique across vehicles and restarts), so that
// an open popup stays open. Unlikely pins (p_person below FAINT_BELOW) are drawn faint; the
// filter (#pin-filter) hides those below its minimum p_person, on the map and in the list.
const FAINT_BELOW = 0.1;
const MAX_PIN_ROWS = 200;  // the list shows the most probable this many
const candidates = new Map();
function seenText(c) {
  const times = (n) => `${n} time${n === 1 ? "" : "s"}`;
  return `seen ${times(c.looks)}, detected ${c.hits}`;
}
function pinFilter() {
  return Number(document.getElementById("pin-filter").value) || 0;
}
function candidatePopup(v, c) {
  const box = el("div", undefined, "candidate-popup");
  box.appendChild(el("strong", `${c.class} ${c.uid} (${v.id})`));
  box.appendChild(el("div", `p_person ${fixed(c.p_person, 4)}`, "p-person"));
  box.appendChild(el("div", seenText(c), "looks"));
  const dl = el("dl");
  for (const [k, val] of [["uid", c.uid], ["p_person", fixed(c.p_person, 4)],
                          ["looks", String(c.looks)], ["hits", String(c.hits)],
                          ["P_D (cell)", fixed(c.pd, 3)], ["P_FA (cell)", fixed(c.pfa, 3)],
                          ["confidence", fixed(c.confidence, 2)],
                          ["position", `${fixed(c.lat_deg, 7)}, ${fixed(c.lon_deg, 7)} ` +
                                       `\u00b1 ${fixed(c.sigma_m, 1)} m`],
                          ["first seen", seenAt(c.first_time_utc, c.first_t_boot_s)],
                          ["last seen", seenAt(c.last_time_utc, c.last_t_boot_s)]]) {
    dl.appendChild(el("dt", k));
    dl.appendChild(el("dd", val));
  }
  box.appendChild(dl);
  return box;
}
function seenAt(utc, bootS) {
  // The UTC of the detection (the autopilot's real-time clock) when the daemon knew it.
  const boot = `${fixed(bootS, 1)} s (boot)`;
  return utc ? `${utc} (${boot})` : boot;
}
function styleCandidate(entry, c) {
  const faint = c.p_person < FAINT_BELOW;
  entry.marker.setOpacity(faint ? 0.35 : 1);
  entry.circle.setStyle({opacity: faint ? 0.3 : 1, fillOpacity: faint ? 0.03 : 0.1});
  const e = entry.marker.getElement();
  if (e) e.classList.toggle("faint", faint);
}
function showCandidates(vehicles) {
  const seen = new Set(), minimum = pinFilter(), all = [];
  for (const v of vehicles) {
    for (const c of v.candidates || []) {
      const key = c.uid, at = [c.lat_deg, c.lon_deg];
      const text = JSON.stringify(c);
      seen.add(key);
      all.push([v, c]);
      let entry = candidates.get(key);
      if (!entry) {
        entry = {marker: L.marker(at, {title: `${c.class} ${c.uid}`}).bindPopup(""),
                 circle: L.circle(at, {radius: c.sigma_m, color: v.color, weight: 1,
                                       fillOpacity: 0.1, interactive: false}),
                 text: null, c};
        entry.marker.on("add", () => {
          entry.marker.getElement().dataset.candidate = key;
          styleCandidate(entry, entry.c);
        });
        candidates.set(key, entry);
      }
      if (entry.text !== text) {
        entry.marker.setLatLng(at).setPopupContent(candidatePopup(v, c));
        entry.circle.setLatLng(at).setRadius(c.sigma_m);
        entry.text = text;
        entry.c = c;
      }
      styleCandidate(entry, c);
      const shown = c.p_person >= minimum;
      if (shown && !layers.candidates.hasLayer(entry.marker)) {
        layers.candidates.addLayer(entry.circle).addLayer(entry.marker);
      } else if (!shown && layers.candidates.hasLayer(entry.marker)) {
        layers.candidates.removeLayer(entry.marker).removeLayer(entry.circle);
      }
    }
  }
  for (const [key, entry] of candidates) {
    if (!seen.has(key)) {
      layers.candidates.removeLayer(entry.marker).removeLayer(entry.circle);
      candidates.delete(key);
    }
  }
  showPinList(all, minimum);
}
// The pins list: the most probable first (ties by uid), those the filter keeps.
function showPinList(all, minimum) {
  const kept = all.filter(([, c]) => c.p_person >= minimum)
    .sort(([, a], [, b]) => b.p_person - a.p_person || (a.uid < b.uid ? -1 : a.uid > b.uid ? 1 : 0));
  const rows = kept.slice(0, MAX_PIN_ROWS).map(([v, c]) => {
    const li = el("li", undefined, c.p_person < FAINT_BELOW ? "faint" : "");
    li.appendChild(el("span", fixed(c.p_person, 2), "p"));
    li.appendChild(el("span", ` ${c.class} ${c.uid} `));
    li.appendChild(el("span", `${c.hits}/${c.looks} looks`, "looks"));
    li.style.borderLeftColor = v.color;
    li.dataset.uid = c.uid;
    li.dataset.pPerson = String(c.p_person);
    li.addEventListener("click", () => {
      const entry = candidates.get(c.uid);
      if (entry) { map.panTo(entry.marker.getLatLng()); entry.marker.openPopup(); }
    });
    return li;
  });
  document.getElementById("pins").replaceChildren(...rows);
  document.getElementById("pins-note").textContent =
    `${kept.length} of ${all.length} pins` + (kept.length > MAX_PIN_ROWS
      ? `; the ${MAX_PIN_ROWS} most probable listed` : "");
}
document.getElementById("pin-filter").addEventListener("change", () => {
  if (state) showCandidates(state.vehicles);
});

function showGaps(gaps) {
  layers.gaps.clearLayers();
  for (const gap of gaps || []) {
    layers.gaps.addLayer(L.polygon(gap, {color: "#ff7800", weight: 2, dashArray: "4 4",
                                         fillOpacity: 0.2}));
  }
}

// The re-fly proposed: its path (the gaps are the gaps layer's). The id marks the map for
// the browser tests.
function showRefly(r) {
  layers.refly.clearLayers();
  mapElement.dataset.reflyId = r ? r.id : "";
  if (r && r.waypoints.length) {
    layers.refly.addLayer(L.polyline(r.waypoints, {color: "#d6008f", weight: 2,
                                                   dashArray: "6 4"}));
  }
}

async function post(url, body) {
  const resp = await fetch(url, {method: "POST", headers: {"Content-Type": "application/json"},
                                 body: JSON.stringify(body), credentials: "same-origin"});
  const doc = await resp.json();
  if (!resp.ok) throw new Error(doc.error || resp.statusText);
  return doc;
}

function reflyLines(lines, outcome) {
  document.getElementById("refly-lines").replaceChildren(...lines.map((text) => el("li", text)));
  document.getElementById("refly-outcome").textContent = outcome || "";
}

document.getElementById("refly-form").addEventListener("submit", async (ev) => {
  ev.preventDefault();
  const target = document.getElementById("refly-target").value;
  const send = document.getElementById("refly-send");
  send.hidden = true;
  reflyLines(["computing the re-fly ..."]);
  try {
    const p = await post("api/refly", {vehicle: document.getElementById("refly-vehicle").value,
                                       target_pd: target ? Number(target) : null});
    reflyLines(p.lines);
    send.dataset.id = p.id; send.textContent = `Send mission ${p.id} to ${p.vehicle}`; send.hidden = false;
  } catch (err) { reflyLines([], `no re-fly: ${err.message}`); }
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

// What this page's token may do (the server refuses commands to a view token all the same).
fetch("api/whoami", {credentials: "same-origin"}).then((r) => r.json()).then((me) => {
  document.getElementById("refly-commands").hidden = !me.may_command;
  document.getElementById("command-note").textContent = me.may_command ? "" : `view only: ${me.why}`;
}).catch(() => {
  document.getElementById("command-note").textContent = "view only: could not ask what this token may do";
});

function showReflyControls(s) {
  const sel = document.getElementById("refly-vehicle");
  const ids = s.vehicles.map((v) => v.id);
  if (sel.options.length !== ids.length || ids.some((id, i) => sel.options[i].value !== id)) {
    sel.replaceChildren(...ids.map((id) => new Option(id, id)));
  }
  document.getElementById("refly-ask").disabled = !s.refly_available || !ids.length;
  if (s.refly_outcome) document.getElementById("refly-outcome").textContent = s.refly_outcome;
}

// The view follows the grid (or domain) until the operator has it; refitted when the grid
// shown moves, never because a track grew.
let fittedTo = null;
function fitView(s) {
  let key = null, bounds = null;
  if (s.grid) {
    key = JSON.stringify(s.grid.bounds_lat_lon); bounds = L.latLngBounds(s.grid.bounds_lat_lon);
  } else if (s.domain) {
    key = s.domain.grid_hash + s.domain.source; bounds = L.latLngBounds(s.domain.boundary_lat_lon);
  } else {
    const points = s.vehicles.flatMap((v) => v.track_lat_lon);
    if (points.length) { key = "tracks"; bounds = L.latLngBounds(points); }
  }
  if (key !== null && key !== fittedTo) {
    map.fitBounds(bounds, {padding: [20, 20], maxZoom: 22});
    fittedTo = key;
  }
}

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
  document.getElementById("roster-note").textContent = s.roster_note || "";
  document.getElementById("layer-notes").textContent = (s.grid && s.grid.outline_note) || "";
  const warnings = document.getElementById("warnings");
  warnings.replaceChildren(...(s.warnings || []).map((text) => el("li", text)));
  document.getElementById("status-line").textContent =
    `${s.vehicles.length} vehicle(s); update ${s.version}; ${new Date().toLocaleTimeString()}`;
  showTables();
  fitView(s);
  showBasemap(s.basemap);
  showHeat(s.grid);
  showOutline(s.grid);
  showDomain(s.domain);
  showPlans(s.plans);
  showVehicles(s.vehicles);
  showCandidates(s.vehicles);
  showGaps(s.gaps);
  showRefly(s.refly);
  showReflyControls(s);
  for (const fn of listeners) fn(s);
}

function colourBar() {
  const c = document.getElementById("colorbar"), cc = c.getContext("2d");
  for (let i = 0; i < c.width; i++) {
    const [R, G, B] = colour(i / (c.width - 1));
    cc.fillStyle = `rgb(${R},${G},${B})`; cc.fillRect(i, 0, 1, c.height);
  }
}

// The server answered this page's ?token= with its cookie: take the token out of the
// address bar, so that it is not left in screenshots, bookmarks or shared links.
const here = new URL(window.location.href);
if (here.searchParams.has("token")) {
  here.searchParams.delete("token");
  history.replaceState(null, "", here.pathname + here.search + here.hash);
}

colourBar();
// An update that cannot be read or drawn is shown, never a silently frozen map: the
// banner says what failed and that the figures shown are those of the last good update.
function showError(what, err) {
  const banner = document.getElementById("error");
  banner.textContent = `${what}: ${err && err.message ? err.message : err}; the map shows the ` +
    `last update that could be read (${state ? "update " + state.version : "none yet"})`;
  banner.hidden = false;
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
