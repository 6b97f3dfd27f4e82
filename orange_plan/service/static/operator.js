// orange-plan operator page: polls the service once a second and draws the mission in SVG.
// No libraries, no external assets. The map frame is metric (x east, y north); the <g id=world>
// flips y so that north is up.
"use strict";

const SVG_NS = "http://www.w3.org/2000/svg";
const POLL_MS = 1000;
const RAMP = ["#440154", "#3b528b", "#21918c", "#5ec962", "#fde725"]; // viridis stops
const SURFACE_COLOURS = ["#d7ccc8", "#c5e1a5", "#b3e5fc", "#ffe0b2", "#e1bee7", "#f0f4c3"];

const state = {
  token: tokenFromPage(),
  mission: new URLSearchParams(location.search).get("mission"),
  planVersion: null,
  mapVersion: null,
  busy: false,
  pixel: 0.05, // metres per screen pixel, for marker sizes
};

function tokenFromPage() {
  const m = /(?:^#|&)token=([^&]+)/.exec(location.hash);
  if (m) {
    sessionStorage.setItem("orange-plan-token", decodeURIComponent(m[1]));
    history.replaceState(null, "", location.pathname + location.search);
  }
  return sessionStorage.getItem("orange-plan-token");
}

const $ = (id) => document.getElementById(id);

class Unauthorised extends Error {}

async function api(path) {
  const headers = { Accept: "application/json" };
  if (state.token) headers.Authorization = "Bearer " + state.token;
  const r = await fetch(path, { headers, cache: "no-store" });
  if (r.status === 401) throw new Unauthorised("token needed");
  if (!r.ok) {
    let detail = r.statusText;
    try { detail = (await r.json()).detail; } catch (e) { /* not JSON */ }
    throw new Error(r.status + ": " + detail);
  }
  return r.json();
}

// --- geometry -> SVG -------------------------------------------------------------------------
function ringPath(ring) {
  return "M" + ring.map((p) => p[0] + " " + p[1]).join("L") + "Z";
}

function geomPath(g) {
  if (!g) return "";
  if (g.type === "Polygon") return g.coordinates.map(ringPath).join("");
  if (g.type === "MultiPolygon") return g.coordinates.map((p) => p.map(ringPath).join("")).join("");
  if (g.type === "GeometryCollection") return g.geometries.map(geomPath).join("");
  return "";
}

function el(tag, attrs, parent) {
  const e = document.createElementNS(SVG_NS, tag);
  for (const [k, v] of Object.entries(attrs || {})) e.setAttribute(k, v);
  if (parent) parent.appendChild(e);
  return e;
}

function clear(id) {
  const g = $(id);
  while (g.firstChild) g.removeChild(g.firstChild);
  return g;
}

function rampColour(f) {
  f = Math.min(1, Math.max(0, isFinite(f) ? f : 0)) * (RAMP.length - 1);
  const i = Math.min(RAMP.length - 2, Math.floor(f));
  const t = f - i;
  const a = hex(RAMP[i]);
  const b = hex(RAMP[i + 1]);
  const c = a.map((v, k) => Math.round(v + t * (b[k] - v)));
  return "rgb(" + c.join(",") + ")";
}

function hex(s) {
  return [1, 3, 5].map((i) => parseInt(s.slice(i, i + 2), 16));
}

// --- drawing ---------------------------------------------------------------------------------
function drawMap(fc) {
  const boundary = fc.features.find((f) => f.properties.kind === "boundary");
  const ring = boundary.geometry.coordinates[0];
  const xs = ring.map((p) => p[0]);
  const ys = ring.map((p) => p[1]);
  const [x0, x1, y0, y1] = [Math.min(...xs), Math.max(...xs), Math.min(...ys), Math.max(...ys)];
  const pad = 0.03 * Math.max(x1 - x0, y1 - y0);
  const w = x1 - x0 + 2 * pad;
  const h = y1 - y0 + 2 * pad;
  $("map").setAttribute("viewBox", [x0 - pad, -(y1 + pad), w, h].join(" "));
  const box = $("map").getBoundingClientRect();
  state.pixel = Math.max(w / Math.max(box.width, 1), h / Math.max(box.height, 1)) || 0.05;
  const hatch = $("hatch");
  if (hatch) {
    const s = 8 * state.pixel;
    hatch.setAttribute("width", s);
    hatch.setAttribute("height", s);
    hatch.querySelector("rect").setAttribute("width", s);
    hatch.querySelector("rect").setAttribute("height", s);
    // the stripe in the middle of its tile: on the tile's edge half of it would be clipped
    const line = hatch.querySelector("line");
    line.setAttribute("x1", s / 2);
    line.setAttribute("x2", s / 2);
    line.setAttribute("y2", s);
    line.setAttribute("stroke-width", 1.5 * state.pixel);
  }
  el("path", { d: geomPath(boundary.geometry) }, clear("boundary"));
  const surfaces = clear("surfaces");
  const names = [];
  for (const f of fc.features.filter((f) => f.properties.kind === "surface")) {
    if (!names.includes(f.properties.name)) names.push(f.properties.name);
    const colour = SURFACE_COLOURS[names.indexOf(f.properties.name) % SURFACE_COLOURS.length];
    const p = el("path", { d: geomPath(f.geometry), fill: colour, "fill-rule": "evenodd" }, surfaces);
    el("title", {}, p).textContent = f.properties.name + " (crr " + f.properties.crr + ")";
  }
  const obstacles = clear("obstacles");
  const nogo = clear("nogo");
  for (const f of fc.features) {
    const kind = f.properties.kind;
    if (kind !== "obstacle" && kind !== "no_go") continue;
    const attrs = { d: geomPath(f.geometry), "fill-rule": "evenodd" };
    if (f.properties.update) attrs.class = "update";
    el("path", attrs, kind === "obstacle" ? obstacles : nogo);
  }
  const home = fc.features.find((f) => f.properties.kind === "home");
  const g = clear("home");
  if (home) {
    const [hx, hy] = home.geometry.coordinates;
    const s = 7 * state.pixel;
    el("path", { d: `M${hx - s} ${hy - s}L${hx + s} ${hy - s}L${hx + s} ${hy + s}L${hx - s} ${hy + s}Z` }, g);
  }
}

function drawPlan(plan) {
  const tour = plan.features.find((f) => f.properties.kind === "tour");
  const covered = plan.features.find((f) => f.properties.kind === "covered");
  el("path", { d: geomPath(covered && covered.geometry), "fill-rule": "nonzero" }, clear("plan-covered"));
  const g = clear("tour");
  const xy = tour.geometry.coordinates;
  const v = tour.properties.speed_mps;
  const lo = Math.min(...v);
  const hi = Math.max(...v);
  for (let i = 0; i + 1 < xy.length; i++) {
    const colour = rampColour(hi > lo ? (v[i] - lo) / (hi - lo) : 0.5);
    const line = el("line", { x1: xy[i][0], y1: xy[i][1], x2: xy[i + 1][0], y2: xy[i + 1][1],
                              stroke: colour }, g);
    el("title", {}, line).textContent = v[i].toFixed(2) + " m/s";
  }
  g.setAttribute("data-vertices", xy.length);
  const wp = clear("waypoints");
  for (const f of plan.features.filter((f) => f.properties.kind === "waypoint")) {
    el("circle", { cx: f.geometry.coordinates[0], cy: f.geometry.coordinates[1], r: 3 * state.pixel }, wp);
  }
  const legend = $("legend");
  legend.innerHTML = "";
  const span = document.createElement("span");
  if (lo.toFixed(2) === hi.toFixed(2)) {
    // one speed throughout: a colour ramp from a value to itself would say nothing
    span.textContent = "planned speed " + lo.toFixed(2) + " m/s throughout";
    legend.append(span);
  } else {
    span.textContent = "planned speed " + lo.toFixed(2) + " m/s";
    legend.append(span, speedRamp(), document.createTextNode(hi.toFixed(2) + " m/s"));
  }
  const s = plan.summary || {};
  $("plan-info").textContent = fmt(s.coverage_m2, 1) + " m², " + fmt(s.duration_s / 60, 1) + " min";
}

function speedRamp() {
  const ramp = document.createElement("span");
  ramp.className = "ramp";
  ramp.style.background = "linear-gradient(to right," + RAMP.join(",") + ")";
  return ramp;
}

function drawLive(live) {
  const cov = clear("covered");
  if (live.covered) el("path", { d: geomPath(live.covered), "fill-rule": "nonzero" }, cov);
  const trail = live.trail_xy_m || [];
  $("trail").setAttribute("points", trail.map((p) => p[0] + "," + p[1]).join(" "));
  const robot = $("robot");
  const pos = live.position_xy_m;
  if (pos) {
    robot.setAttribute("cx", pos[0]);
    robot.setAttribute("cy", pos[1]);
    robot.setAttribute("r", 6 * state.pixel);
    robot.setAttribute("visibility", "visible");
  }
  const d = live.decision || {};
  const action = $("action");
  action.textContent = (d.action || "–").replace("_", " ");
  action.className = "action " + (d.action || "");
  $("reason").textContent = d.reason || "";
  $("margin").textContent = energy(d.homing_margin_J);
  $("probability").textContent = d.return_probability == null ? "–"
    : (100 * d.return_probability).toFixed(d.return_probability > 0.999 ? 3 : 1) + " %";
  $("energy").textContent = energy(live.energy_used_J);
  $("tohome").textContent = energy(d.energy_to_home_J);
  $("reserve").textContent = energy(d.reserve_J);
  $("range").textContent = d.remaining_range_m == null ? "–" : fmt(d.remaining_range_m, 1) + " m";
  $("time").textContent = fmt(live.time_s, 1) + " s";
  $("position").textContent = pos ? "(" + fmt(pos[0], 2) + ", " + fmt(pos[1], 2) + ") m" : "–";
  $("covered-area").textContent = d.covered_m2 == null ? "–" : fmt(d.covered_m2, 1) + " m²";
  $("samples").textContent = live.samples + " in " + live.batches + " batches";
}

function fmt(x, digits) {
  return x == null || !isFinite(x) ? "–" : Number(x).toFixed(digits);
}

function energy(j) {
  if (j == null || !isFinite(j)) return "–";
  return Math.abs(j) >= 1e4 ? (j / 1e3).toFixed(2) + " kJ" : j.toFixed(0) + " J";
}

// --- polling ---------------------------------------------------------------------------------
async function refreshMissions() {
  const { missions } = await api("/missions");
  const select = $("mission");
  const ids = missions.map((m) => m.mission_id);
  if (select.options.length !== ids.length) {
    select.innerHTML = "";
    for (const m of missions) {
      const o = document.createElement("option");
      o.value = m.mission_id;
      o.textContent = m.scenario + " · " + m.mission_id;
      select.appendChild(o);
    }
  }
  if (!state.mission || !ids.includes(state.mission)) state.mission = ids[ids.length - 1] || null;
  if (state.mission) select.value = state.mission;
}

async function tick() {
  if (state.busy) return;
  state.busy = true;
  try {
    await refreshMissions();
    if (!state.mission) {
      $("action").textContent = "no mission";
      $("connection").textContent = "connected · no missions yet";
      return;
    }
    const id = encodeURIComponent(state.mission);
    const live = await api("/missions/" + id + "/live");
    if (live.map_version !== state.mapVersion) {
      drawMap(await api("/missions/" + id + "/map"));
      state.mapVersion = live.map_version;
      state.planVersion = null; // marker sizes follow the map's scale
    }
    if (live.plan_version !== state.planVersion) {
      drawPlan(await api("/missions/" + id + "/plan"));
      state.planVersion = live.plan_version;
    }
    drawLive(live);
    $("connection").textContent = "live · " + new Date().toLocaleTimeString();
    $("connection").className = "muted";
  } catch (e) {
    if (e instanceof Unauthorised) {
      $("token-form").hidden = false;
      $("connection").textContent = "this server needs its token";
    } else {
      $("connection").textContent = "error: " + e.message;
    }
    $("connection").className = "error";
  } finally {
    state.busy = false;
  }
}

$("mission").addEventListener("change", (ev) => {
  state.mission = ev.target.value;
  state.mapVersion = null;
  state.planVersion = null;
  tick();
});

$("token-form").addEventListener("submit", (ev) => {
  ev.preventDefault();
  state.token = $("token").value;
  sessionStorage.setItem("orange-plan-token", state.token);
  $("token-form").hidden = true;
  tick();
});

tick();
setInterval(tick, POLL_MS);
