// fuseplan's status page: the flight drawn from its event records (the same ones as events.jsonl), streamed as
// Server-Sent Events from /events. Read-only: the page sends nothing but GET requests. Local metres, north up.
"use strict";

const SVG = "http://www.w3.org/2000/svg";
const MAX_TRACK = 4000; // points of the flown track kept (thinned by half beyond that)
const MAX_LOG = 300;
const AUTOPILOTS = { 3: "ArduPilot", 12: "PX4" };
const $ = (id) => document.getElementById(id);

let S; // the page's picture of the flight, rebuilt from scratch on every (re)connection

function fresh() {
  return { scene: null, size: 1000, items: [], current: null, reached: new Set(), track: [], contacts: new Map(),
           replans: new Map(), conflictWith: new Set(), events: 0 };
}

function el(tag, attrs = {}, parent = null) {
  const e = document.createElementNS(SVG, tag);
  for (const [k, v] of Object.entries(attrs)) e.setAttribute(k, v);
  if (parent) parent.appendChild(e);
  return e;
}
const pts = (list) => list.map((p) => `${p[0]},${-p[1]}`).join(" ");
const fmt = (v, d = 1) => (v === null || v === undefined ? "-" : Number(v).toFixed(d));

function clear() {
  S = fresh();
  for (const id of ["static", "threat-paths", "mission", "replans", "contacts"]) $(id).replaceChildren();
  $("route").setAttribute("points", "");
  $("track").setAttribute("points", "");
  $("vehicle").setAttribute("hidden", "");
  $("log").replaceChildren();
  $("replan-table").tBodies[0].replaceChildren();
  $("contact-list").replaceChildren(Object.assign(document.createElement("li"), { className: "none", textContent: "none" }));
  for (const id of ["hold", "result"]) $(id).hidden = true;
  document.body.dataset.finished = "";
}

function chip(id, text, state) {
  const c = $(id);
  c.textContent = text;
  if (state !== undefined) c.dataset.state = state;
}

function log(rec, text, cls = "") {
  const li = document.createElement("li");
  li.textContent = `[${fmt(rec.t, 1).padStart(6)} s] ${text}`;
  if (cls) li.className = cls;
  li.dataset.event = rec.event;
  const ol = $("log");
  ol.prepend(li);
  while (ol.children.length > MAX_LOG) ol.lastChild.remove();
}

function drawScene(sc) {
  S.scene = sc;
  S.size = Math.max(sc.bounds.x, sc.bounds.y);
  const m = 0.04 * S.size;
  $("map").setAttribute("viewBox", `${-m} ${-sc.bounds.y - m} ${sc.bounds.x + 2 * m} ${sc.bounds.y + 2 * m}`);
  $("scenario").textContent = `${sc.name} (${sc.vehicle})`;
  const g = $("static");
  g.replaceChildren();
  el("rect", { id: "bounds", x: 0, y: -sc.bounds.y, width: sc.bounds.x, height: sc.bounds.y }, g);
  const step = niceStep(S.size / 8);
  for (let x = step; x < sc.bounds.x; x += step) el("line", { class: "grid", x1: x, x2: x, y1: 0, y2: -sc.bounds.y }, g);
  for (let y = step; y < sc.bounds.y; y += step) el("line", { class: "grid", x1: 0, x2: sc.bounds.x, y1: -y, y2: -y }, g);
  label(g, 0, -sc.bounds.y - 0.012 * S.size, `grid ${step} m`, "start");
  for (const [x, y, r] of sc.cylinders) el("circle", { class: "cylinder", cx: x, cy: -y, r }, g);
  for (const p of sc.prisms || []) {
    const cls = p.keep_in ? "keep-in" : p.slab ? "prism slab" : "prism";
    el("polygon", { class: cls, points: pts(p.xy) }, g);
  }
  for (const [x, y, _z, r] of sc.spheres) el("circle", { class: "sphere", cx: x, cy: -y, r }, g);
  for (const [x, y, _z, r] of sc.radars) el("circle", { class: "radar", cx: x, cy: -y, r }, g);
  const tp = $("threat-paths");
  tp.replaceChildren();
  for (const [id, path] of Object.entries(sc.threat_paths)) {
    el("polyline", { class: "threat-path", points: pts(path), "data-id": id }, tp);
  }
  $("route").setAttribute("points", pts(sc.route));
  const [s, e] = [sc.route[0], sc.route[sc.route.length - 1]];
  const [hx, hy] = sc.launch || [0, 0];
  el("circle", { class: "home", cx: hx, cy: -hy, r: 0.006 * S.size }, g);
  label(g, hx + 0.01 * S.size, -hy - 0.015 * S.size, "home", "start");
  label(g, s[0], -s[1] - 0.02 * S.size, "start");
  label(g, e[0], -e[1] - 0.02 * S.size, "goal");
  const v = $("vehicle");
  v.dataset.scale = 0.018 * S.size;
}

function niceStep(raw) {
  const p = 10 ** Math.floor(Math.log10(raw));
  return [1, 2, 5, 10].map((k) => k * p).find((s) => s >= raw);
}

function label(parent, x, y, text, anchor = "middle") {
  const t = el("text", { x, y, "font-size": 0.022 * S.size, "text-anchor": anchor, "stroke-width": 0.004 * S.size }, parent);
  t.textContent = text;
  return t;
}

function drawMission(rec) {
  S.items = rec.items;
  const g = $("mission");
  g.replaceChildren();
  el("polyline", { points: pts(rec.items.map((i) => [i[1], i[2]])) }, g);
  for (const [seq, x, y] of rec.items) {
    el("circle", { cx: x, cy: -y, r: 0.006 * S.size, "data-seq": seq }, g);
  }
  markItems();
  $("mission-info").textContent = `${rec.count} items`;
}

function markItems() {
  for (const c of $("mission").querySelectorAll("circle")) {
    const seq = Number(c.dataset.seq);
    c.classList.toggle("current", seq === S.current);
    c.classList.toggle("reached", S.reached.has(seq));
  }
  if (S.current !== null) chip("item", `item ${S.current} of ${S.items.length ? S.items[S.items.length - 1][0] : "?"}`);
}

function position(rec) {
  S.track.push([rec.x, rec.y]);
  if (S.track.length > MAX_TRACK) S.track = S.track.filter((_p, i) => i % 2 === 0 || i === S.track.length - 1);
  $("track").setAttribute("points", pts(S.track));
  const v = $("vehicle");
  v.removeAttribute("hidden");
  const heading = rec.hdg === null || rec.hdg === undefined ? 90 : rec.hdg;
  v.setAttribute("transform", `translate(${rec.x},${-rec.y}) rotate(${heading - 90}) scale(${v.dataset.scale || 15})`);
  v.dataset.x = rec.x;
  v.dataset.y = rec.y;
  v.dataset.z = rec.z;
  v.dataset.t = rec.t;
  $("pos").textContent = `${fmt(rec.x)} m, ${fmt(rec.y)} m`;
  $("alt").textContent = `${fmt(rec.z)} m above home`;
  $("gs").textContent = `${fmt(rec.gs)} m/s`;
}

function drawContacts(list) {
  const g = $("contacts");
  const seen = new Set();
  for (const c of list) {
    seen.add(c.id);
    let node = g.querySelector(`[data-id="${CSS.escape(c.id)}"]`);
    if (!node) {
      node = el("g", { class: `contact ${c.source}`, "data-id": c.id }, g);
      el("polyline", {}, node);
      el("circle", {}, node);
      label(node, 0, 0, c.id);
    }
    node.classList.toggle("conflict", S.conflictWith.has(c.id));
    node.querySelector("polyline").setAttribute("points", pts(c.path));
    const circle = node.querySelector("circle");
    circle.setAttribute("cx", c.p[0]);
    circle.setAttribute("cy", -c.p[1]);
    circle.setAttribute("r", c.r);
    const t = node.querySelector("text");
    t.setAttribute("x", c.p[0]);
    t.setAttribute("y", -c.p[1] - c.r - 0.01 * S.size);
    node.dataset.x = c.p[0];
    node.dataset.y = c.p[1];
    S.contacts.set(c.id, c);
  }
  for (const node of [...g.children]) {
    if (!seen.has(node.dataset.id)) { node.remove(); S.contacts.delete(node.dataset.id); }
  }
  const ul = $("contact-list");
  ul.replaceChildren();
  for (const c of S.contacts.values()) {
    const li = document.createElement("li");
    li.dataset.id = c.id;
    li.textContent = `${c.id} (${c.source === "adsb" ? "ADS-B" : c.kind}) at ${fmt(c.p[0], 0)}, ${fmt(c.p[1], 0)} m, ` +
      `alt ${fmt(c.p[2], 0)} m, radius ${fmt(c.r, 0)} m`;
    if (S.conflictWith.has(c.id)) li.className = "conflict";
    ul.appendChild(li);
  }
  if (!ul.children.length) ul.appendChild(Object.assign(document.createElement("li"), { className: "none", textContent: "none" }));
}

function replanRow(n) {
  let r = S.replans.get(n);
  if (!r) {
    r = { n };
    S.replans.set(n, r);
    const tr = document.createElement("tr");
    tr.dataset.n = n;
    $("replan-table").tBodies[0].appendChild(tr);
  }
  return r;
}

function renderReplan(r) {
  const tr = $("replan-table").querySelector(`tr[data-n="${r.n}"]`);
  tr.className = r.failed ? "failed" : "";
  tr.replaceChildren(...[`R${r.n}`, r.threat || "-", r.plan_s !== undefined ? `${fmt(r.plan_s, 3)} s` : "-",
    r.latency_s !== undefined && r.latency_s !== null ? `${fmt(r.latency_s, 3)} s` : "-", r.outcome || "planning"]
    .map((text) => Object.assign(document.createElement("td"), { textContent: text })));
  let g = $("replans").querySelector(`g[data-n="${r.n}"]`);
  if (!g && r.new_route) {
    g = el("g", { class: "replan", "data-n": r.n }, $("replans"));
    el("polyline", { class: "old-route", points: pts(r.old_route || []) }, g);
    el("polyline", { class: "new-route", points: pts(r.new_route) }, g);
    const c = r.commit || r.new_route[0];
    const w = 0.012 * S.size;
    el("rect", { class: "commit", x: c[0] - w / 2, y: -c[1] - w / 2, width: w, height: w }, g);
    label(g, c[0] + w, -c[1] - w, `R${r.n}`, "start");
  }
  if (g) {
    g.classList.toggle("failed", !!r.failed);
    g.classList.toggle("live", r.outcome === "new mission current");
    if (r.latency_s !== undefined && r.latency_s !== null) g.dataset.latency = r.latency_s;
  }
}

// EVENT_TONES (event -> quiet, plain, good, warn or bad) is the companion's event catalogue, served before this
// script (companion/mission/events.py); an event it does not know is a plain line
const tone = (e) => EVENT_TONES[e] || "plain";

function apply(rec) {
  S.events += 1;
  document.body.dataset.events = S.events;
  const e = rec.event;
  switch (e) {
    case "scene": drawScene(rec); break;
    case "mission": drawMission(rec); break;
    case "position": position(rec); break;
    case "contacts": drawContacts(rec.contacts); break;
    case "sim_started": $("autopilot").textContent = "built-in simulator"; break;
    case "connected":
      chip("link", `link: up (system ${rec.system})`, "up");
      $("autopilot").textContent = `${AUTOPILOTS[rec.autopilot] || `MAV_AUTOPILOT ${rec.autopilot}`}` +
        ($("autopilot").textContent === "built-in simulator" ? " (built-in simulator)" : "");
      chip("mode", `mode: ${rec.mode}`);
      chip("armed", rec.armed ? "ARMED" : "disarmed", rec.armed ? "armed" : "none");
      break;
    case "link_lost": chip("link", `link: LOST (${fmt(rec.age_s)} s)`, "lost"); break;
    case "link_restored": chip("link", "link: up (restored)", "up"); break;
    case "mode": chip("mode", `mode: ${rec.mode}`); break;
    case "armed": chip("armed", "ARMED", "armed"); break;
    case "disarmed": chip("armed", "disarmed", "none"); break;
    case "current": case "set_current": S.current = rec.seq; markItems(); break;
    case "reached": S.reached.add(rec.seq); markItems(); break;
    case "conflict":
      S.conflictWith.add(rec.threat);
      Object.assign(replanRow(rec.n), { threat: rec.threat });
      renderReplan(S.replans.get(rec.n));
      break;
    case "replan_planned":
      Object.assign(replanRow(rec.n), { plan_s: rec.plan_s, status: rec.status, commit: rec.commit,
                                        old_route: rec.old_route, new_route: rec.new_route, outcome: "uploading" });
      renderReplan(S.replans.get(rec.n));
      break;
    case "replanned":
      Object.assign(replanRow(rec.n), { latency_s: rec.latency_s, outcome: rec.outcome, plan_s: rec.plan_s,
                                        threat: rec.threat, failed: false });
      renderReplan(S.replans.get(rec.n));
      break;
    case "replan_skipped": case "replan_stale": case "replan_not_live":
      Object.assign(replanRow(rec.n), { failed: true, outcome: rec.outcome || rec.reason || e.replace("replan_", "") });
      renderReplan(S.replans.get(rec.n));
      break;
    case "track_expired":
      S.conflictWith.delete(rec.id);
      break;
    case "hold": {
      const last = S.replans.get(Math.max(0, ...S.replans.keys()));
      if (last && last.outcome === "uploading" && !["exact", "approximate"].includes(last.status)) {
        Object.assign(last, { failed: true, outcome: `no safe plan (${last.status}): holding` });  // never flown
        renderReplan(last);
      }
      $("hold").hidden = false;
      $("hold").textContent = `HOLD (${rec.mode})`;
      $("vehicle").classList.add("holding");
      break;
    }
    case "resume": $("hold").hidden = true; $("vehicle").classList.remove("holding"); break;
    case "finished": case "failed": case "aborted": {
      const ok = e === "finished" && rec.completed;
      chip("result", ok ? "COMPLETED" : `NOT COMPLETED: ${rec.reason || rec.error || e}`, ok ? "completed" : "failed");
      $("result").hidden = false;
      document.body.dataset.finished = ok ? "completed" : "failed";
      break;
    }
    default: break;
  }
  const t = tone(e);
  if (t !== "quiet") log(rec, describe(rec), t === "plain" ? "" : t);
}

function describe(rec) {
  const e = rec.event;
  if (e === "conflict") return `CONFLICT with ${rec.threat} in ${fmt(rec.in_s)} s: separation ${fmt(rec.separation_m)} m -> replan ${rec.n}`;
  if (e === "replan_planned") return `replan ${rec.n}: ${rec.status} in ${fmt(rec.plan_s, 3)} s, ${rec.waypoints} waypoints`;
  if (e === "replanned") return `replan ${rec.n}: ${rec.outcome}, ${fmt(rec.latency_s, 3)} s after the conflict was seen`;
  if (e === "statustext") return `autopilot: ${rec.text}`;
  if (e === "status_skipped") return `${rec.records} records skipped: ${rec.note}`;
  const rest = Object.entries(rec).filter(([k]) => k !== "t" && k !== "event")
    .map(([k, v]) => `${k}=${typeof v === "object" ? JSON.stringify(v) : v}`).join(" ");
  return `${e} ${rest}`.trim();
}

function connect() {
  const token = new URLSearchParams(location.search).get("token");
  const src = new EventSource(token ? `events?token=${encodeURIComponent(token)}` : "events");
  src.addEventListener("reset", () => { clear(); chip("stream", "page: live", "live"); });
  src.onmessage = (m) => {
    try { apply(JSON.parse(m.data)); } catch (err) { console.error(err, m.data); }
  };
  src.onerror = () => {
    const over = document.body.dataset.finished;
    chip("stream", over ? "page: flight over, companion gone" : "page: reconnecting", "closed");
    if (over) src.close();
  };
}

clear();
connect();
