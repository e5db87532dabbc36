// fleet-view page: draws the frames the server pushes over /ws on a 2D canvas.
// No framework, no network beyond this server. Frame format: clients/viewer/state.py.
"use strict";

(() => {
  const canvas = document.getElementById("view");
  const ctx = canvas.getContext("2d", { alpha: false });
  const $ = (id) => document.getElementById(id);

  const COLORS = {
    bg: "#0b1016", floor: "#121b24", grid: "#1e2a36", bounds: "#344658",
    obstacle: "#3a4a5e", obstacleEdge: "#788ea8", robotEdge: "#080a0e",
    heading: "#fafafa", text: "#e2e8f0", muted: "#8c9aaa", select: "#ffffff",
  };
  const ROBOTS_PAD = 1.5; // m around the robots when the world has no geometry to frame
  // Navigation states (protocol/navigation.py): the colour of a robot's badge in the list, of
  // the legend, and of the ring round a robot that is navigating but not simply driving.
  const NAV_STATES = ["planning", "driving", "waiting", "yielding", "blocked", "overridden", "reached", "failed"];
  const NAV_COLORS = {
    planning: "#9fb3c8", driving: "#06d6a0", waiting: "#ffd166", yielding: "#fb8500",
    blocked: "#ff595e", overridden: "#f72585", reached: "#52f2a0", failed: "#ff595e",
  };
  const NAV_RING = new Set(["planning", "waiting", "yielding", "blocked", "overridden"]);
  const FLASH_MS = 1200; // a robot whose goal ended flashes this long (green reached, red failed)
  const PATHS_FEW = 50; // up to this many paths they are drawn stronger
  const PATH_OFF_M = 0.3; // a robot farther than this from its path is not joined to it
  const navColor = (state) => NAV_COLORS[state] || COLORS.muted;
  const LABEL_MAX = 400; // robots in view above which labels are drawn only when zoomed in

  // ---- state ------------------------------------------------------------------------------
  const S = {
    world: null,          // {name, bounds:[x0,y0,x1,y1], polygons:[[x,y,...]], circles:[[x,y,r]]}
    meta: null,           // {version, palette, footprints, robots:[[ns,name,model,fp,color]]}
    index: new Map(),     // ns -> row index in meta.robots
    reach: [],            // per footprint: farthest vertex from the origin (m)
    frame: null,          // the latest decoded frame
    drawnSeq: 0,
    view: { cx: 0, cy: 0, scale: 50 },  // world centre of the canvas, CSS px per metre
    width: 0, height: 0, dpr: 1,
    autoFit: true,        // until the user pans or zooms, keep the content framed
    edges: [],            // obstacle outline segments [x0, y0, x1, y1]
    fitted: null,         // robots rectangle last auto-fitted (obstacle-free worlds)
    selected: null,
    follow: false,
    opts: { scans: true, trails: true, labels: true, paths: true },
    dirty: true,
    ws: null,
    map: null,            // the live map layer (fleet-view --map): {img, x0, y0, res}
    nav: new Map(),       // ns -> {goalId, state, x, y, yaw|null, tol, other, reason, ended, endedAt}
    paths: new Map(),     // ns -> {pts: [x0, y0, ...], n, rem: length from point j to the goal, k: progress}
    navSeen: false,       // a nav message came: the legend shows from then on
  };

  const stats = {
    clock: null, // the daemon's clock: {rtf, target, behind_s, falling_behind, paused, lockstep}
    frames: 0, fps: 0, msgs: 0, robots: 0, scans: 0, scanPoints: 0, trails: 0, trailPoints: 0,
    beamStep: 1, bytes: 0, drawMs: 0, simTime: 0, seq: 0, skipped: 0, connected: false,
    world: "", metaVersion: -1, navMsgs: 0,
  };
  const drawTimes = [];
  window.viewerStats = stats;

  // World (x right, y up, metres) <-> canvas CSS pixels.
  const sx = (x) => (x - S.view.cx) * S.view.scale + S.width / 2;
  const sy = (y) => S.height / 2 - (y - S.view.cy) * S.view.scale;
  const wx = (px) => S.view.cx + (px - S.width / 2) / S.view.scale;
  const wy = (py) => S.view.cy - (py - S.height / 2) / S.view.scale;

  function hexRgb(hex) {
    return [1, 3, 5].map((i) => parseInt(hex.slice(i, i + 2), 16));
  }
  function robotColor(row) {
    const pal = S.meta ? S.meta.palette : ["#4cc9f0"];
    return pal[row[4] % pal.length];
  }
  function robotPose(i) {
    const p = S.frame && S.frame.poses;
    if (!p || 5 * i + 4 >= p.length) return null;
    return { x: p[5 * i], y: p[5 * i + 1], yaw: p[5 * i + 2], v: p[5 * i + 3], w: p[5 * i + 4] };
  }

  // Test and debugging hooks (page pixels, colours, robot state).
  stats.toScreen = (x, y) => {
    const r = canvas.getBoundingClientRect();
    return [r.left + sx(x), r.top + sy(y)];
  };
  stats.colorOf = (ns) => {
    const i = S.index.get(ns);
    return i === undefined ? null : hexRgb(robotColor(S.meta.robots[i]));
  };
  stats.robot = (ns) => {
    const i = S.index.get(ns);
    if (i === undefined) return null;
    const row = S.meta.robots[i];
    return { namespace: row[0], name: row[1], model: row[2], ...robotPose(i) };
  };
  stats.names = () => (S.meta ? S.meta.robots.map((r) => r[0]) : []);
  stats.select = (ns) => select(ns);
  stats.view = () => ({ ...S.view, width: S.width, height: S.height });
  stats.nav = (ns) => {
    const g = S.nav.get(ns), p = S.paths.get(ns);
    if (!g && !p) return null;
    return {
      goalId: g ? g.goalId : "", state: g ? g.state : null, ended: g ? g.ended : false,
      goal: g ? { x: g.x, y: g.y, yaw: g.yaw, tolerance: g.tol } : null,
      other: g ? g.other : "", reason: g ? g.reason : "",
      path: p ? p.n : 0, pathPoints: p ? Array.from(p.pts) : [], left: navLeft(ns),
    };
  };
  stats.navCounts = () => navCounts();

  // ---- connection -------------------------------------------------------------------------
  function connect() {
    const proto = location.protocol === "https:" ? "wss:" : "ws:";
    const ws = new WebSocket(`${proto}//${location.host}/ws`);
    ws.binaryType = "arraybuffer";
    S.ws = ws;
    ws.onopen = () => {
      stats.connected = true;
      stats.clock = null; // the new connection's first frame carries it
      // a new connection starts from nothing: the server sends every goal and path again,
      // and goals that ended while the page was away must not linger
      S.nav.clear();
      S.paths.clear();
      sendView(true);
      updateStatus();
    };
    ws.onclose = () => {
      stats.connected = false;
      S.ws = null;
      updateStatus();
      setTimeout(connect, 1000);
    };
    ws.onmessage = (ev) => {
      if (typeof ev.data === "string") {
        const msg = JSON.parse(ev.data);
        if (msg.type === "world") onWorld(msg);
        else if (msg.type === "meta") onMeta(msg);
        else if (msg.type === "nav") onNav(msg);
        return;
      }
      const f = decodeFrame(ev.data);
      if ("clock" in f) stats.clock = f.clock; // only when it changed (about once a second)
      if (!S.meta || f.meta !== S.meta.version) return; // cannot happen: meta comes first
      S.frame = f;
      stats.msgs += 1;
      stats.bytes = ev.data.byteLength;
      S.dirty = true;
      // Received: the server may send the next one. Only the latest frame is ever drawn;
      // a page too busy to run this handler stops the acks and the server skips ticks.
      ws.send(`{"type":"ack","seq":${f.seq}}`);
    };
  }

  function decodeFrame(buf) {
    const dv = new DataView(buf);
    const hlen = dv.getUint32(0, true);
    const h = JSON.parse(new TextDecoder().decode(new Uint8Array(buf, 4, hlen)));
    let off = 4 + hlen;
    const take = (Type, n) => {
      const a = new Type(buf, off, n);
      off += n * Type.BYTES_PER_ELEMENT;
      return a;
    };
    h.poses = take(Float32Array, 5 * h.n);
    h.scanIdx = take(Uint32Array, h.scans);
    h.scanCnt = take(Uint32Array, h.scans);
    h.scanPts = take(Float32Array, 2 * h.scan_points);
    h.trailIdx = take(Uint32Array, h.trails);
    h.trailCnt = take(Uint32Array, h.trails);
    h.trailPts = take(Float32Array, 2 * h.trail_points);
    return h;
  }

  // Polygon edges minus those two polygons share: a wall split into convex pieces is
  // outlined as one shape (same rule as snapshot.outer_edges).
  function outerEdges(polygons) {
    const key = (x0, y0, x1, y1) => {
      const a = `${x0.toFixed(4)},${y0.toFixed(4)}`, b = `${x1.toFixed(4)},${y1.toFixed(4)}`;
      return a < b ? `${a}|${b}` : `${b}|${a}`;
    };
    const edges = [];
    for (const p of polygons) {
      for (let i = 0; i < p.length; i += 2) {
        const j = (i + 2) % p.length;
        edges.push([p[i], p[i + 1], p[j], p[j + 1]]);
      }
    }
    const count = new Map();
    for (const e of edges) count.set(key(...e), (count.get(key(...e)) || 0) + 1);
    return edges.filter((e) => count.get(key(...e)) === 1);
  }

  function onWorld(msg) {
    S.world = msg;
    S.edges = outerEdges(msg.polygons);
    stats.world = msg.name;
    $("world-name").textContent = msg.name || "(no world)";
    document.title = `fleet-view · ${msg.name}`;
    worldCache.key = "";
    if (S.autoFit) fitContent();
    S.dirty = true;
  }

  function onMeta(msg) {
    S.meta = msg;
    S.index = new Map(msg.robots.map((r, i) => [r[0], i]));
    S.reach = msg.footprints.map((fp) => {
      let m = 0.05;
      for (let i = 0; i < fp.length; i += 2) m = Math.max(m, Math.hypot(fp[i], fp[i + 1]));
      return m;
    });
    stats.metaVersion = msg.version;
    stats.robots = msg.robots.length;
    if (S.selected && !S.index.has(S.selected)) select(null);
    S.frame = null; // frames of the old version no longer line up
    renderList();
    S.dirty = true;
  }

  // ---- navigation: goals, states and paths (clients/viewer/navigation.py sends what changed) ----
  function onNav(msg) {
    stats.navMsgs += 1;
    S.navSeen = true;
    const now = performance.now();
    const changed = [];
    for (const [ns, row] of Object.entries(msg.goals || {})) {
      changed.push(ns);
      if (!Array.isArray(row) || row.length < 6 || !Number.isFinite(row[2]) || !Number.isFinite(row[3])) {
        S.nav.delete(ns);
        continue;
      }
      const [goalId, state, x, y, yaw, tol, other, reason] = row;
      const old = S.nav.get(ns);
      const ended = state === "reached" || state === "failed";
      const again = old && old.ended && old.goalId === goalId;
      S.nav.set(ns, {
        goalId: String(goalId), state: String(state), x, y,
        yaw: Number.isFinite(yaw) ? yaw : null, tol: Number.isFinite(tol) ? Math.max(0, tol) : 0,
        other: other ? String(other) : "", reason: reason ? String(reason) : "",
        ended, endedAt: ended ? (again ? old.endedAt : now) : null,
      });
    }
    for (const [ns, flat] of Object.entries(msg.paths || {})) {
      const p = Array.isArray(flat) ? makePath(flat) : null;
      if (p) S.paths.set(ns, p);
      else S.paths.delete(ns);
    }
    for (const ns of changed) updateListItem(ns);
    renderLegend();
    updateSelected();
    S.dirty = true;
  }

  function makePath(flat) {
    const n = flat.length >> 1;
    if (n < 2) return null;
    const pts = new Float64Array(2 * n);
    for (let i = 0; i < 2 * n; i++) {
      pts[i] = +flat[i];
      if (!Number.isFinite(pts[i])) return null;
    }
    const rem = new Float64Array(n);
    for (let j = n - 2; j >= 0; j--) rem[j] = rem[j + 1] + Math.hypot(pts[2 * j + 2] - pts[2 * j], pts[2 * j + 3] - pts[2 * j + 1]);
    return { pts, n, rem, k: 0 };
  }

  // The point of segment a-b nearest to (x, y): [t along it, distance].
  function onSegment(x, y, ax, ay, bx, by) {
    const dx = bx - ax, dy = by - ay, l2 = dx * dx + dy * dy;
    const t = l2 > 0 ? Math.min(1, Math.max(0, ((x - ax) * dx + (y - ay) * dy) / l2)) : 0;
    return [t, Math.hypot(x - ax - t * dx, y - ay - t * dy)];
  }

  // Where the robot is along its path: the nearest segment from the one it was on, a few
  // ahead at most (it does not go back), and the nearest point of it (p.px, p.py, p.off m
  // away). The drawing starts there, not at the path's start; the distance left is measured
  // from there.
  function advance(p, x, y) {
    let best = p.k, bestD = Infinity, bestT = 0;
    const last = Math.min(p.n - 2, p.k + 40);
    for (let j = p.k; j <= last; j++) {
      const [t, d] = onSegment(x, y, p.pts[2 * j], p.pts[2 * j + 1], p.pts[2 * j + 2], p.pts[2 * j + 3]);
      if (d <= bestD) { best = j; bestD = d; bestT = t; }
    }
    p.k = best;
    const j = 2 * best;
    p.px = p.pts[j] + bestT * (p.pts[j + 2] - p.pts[j]);
    p.py = p.pts[j + 1] + bestT * (p.pts[j + 3] - p.pts[j + 1]);
    p.off = bestD;
  }

  function navLeft(ns) {
    const p = S.paths.get(ns);
    const i = S.index.get(ns);
    const pose = i === undefined ? null : robotPose(i);
    if (!p || !pose) return null;
    advance(p, pose.x, pose.y);
    const j = p.k + 1;
    return p.off + Math.hypot(p.pts[2 * j] - p.px, p.pts[2 * j + 1] - p.py) + p.rem[j];
  }

  function navCounts() {
    const counts = {};
    for (const g of S.nav.values()) counts[g.state] = (counts[g.state] || 0) + 1;
    return counts;
  }

  function navText(g) {
    let t = g.state;
    if (g.other) t += ` (${g.other})`;
    if (g.state === "failed" && g.reason && g.reason !== "failed") t += `: ${g.reason}`;
    return t;
  }

  function renderLegend() {
    $("navigation").hidden = !S.navSeen;
    const counts = navCounts();
    let active = 0;
    for (const g of S.nav.values()) if (!g.ended) active += 1;
    $("nav-count").textContent = active;
    const known = new Set(NAV_STATES);
    const states = NAV_STATES.concat(Object.keys(counts).filter((k) => !known.has(k)).sort());
    $("nav-legend").innerHTML = states.map((st) =>
      `<span class="legend-item${counts[st] ? "" : " none"}">` +
      `<span class="swatch" style="background:${navColor(st)}"></span>${escapeHtml(st)} ${counts[st] || 0}</span>`,
    ).join("");
  }

  let viewTimer = null;
  let lastView = "";
  function sendView(now) {
    if (viewTimer) return;
    const go = () => {
      viewTimer = null;
      if (!S.ws || S.ws.readyState !== WebSocket.OPEN) return;
      const rect = [wx(0), wy(S.height), wx(S.width), wy(0)].map((v) => +v.toFixed(2));
      const msg = JSON.stringify({
        type: "view", rect, scans: S.opts.scans, trails: S.opts.trails, selected: S.selected,
      });
      if (msg !== lastView || now) S.ws.send(msg);
      lastView = msg;
    };
    if (now) go();
    else viewTimer = setTimeout(go, 80);
  }

  // ---- view -------------------------------------------------------------------------------
  function robotsRect() {
    const f = S.frame;
    if (!f || f.n === 0) return null;
    let x0 = Infinity, y0 = Infinity, x1 = -Infinity, y1 = -Infinity;
    for (let i = 0; i < f.n; i++) {
      const x = f.poses[5 * i], y = f.poses[5 * i + 1];
      if (x < x0) x0 = x; if (x > x1) x1 = x;
      if (y < y0) y0 = y; if (y > y1) y1 = y;
    }
    return [x0 - ROBOTS_PAD, y0 - ROBOTS_PAD, x1 + ROBOTS_PAD, y1 + ROBOTS_PAD];
  }
  function worldRect() {
    const w = S.world;
    return w && w.bounds ? w.bounds : null;
  }
  function fitRect(r) {
    if (!r || !S.width) return;
    const m = 0.04 * Math.min(S.width, S.height);
    const top = Math.max(m, 52); // keep the content clear of the toolbar
    const scale = Math.min((S.width - 2 * m) / Math.max(r[2] - r[0], 1e-3),
                           (S.height - m - top) / Math.max(r[3] - r[1], 1e-3));
    const cy = (r[1] + r[3]) / 2 + (top - m) / 2 / scale;
    S.view = { cx: (r[0] + r[2]) / 2, cy, scale: clampScale(scale) };
    S.dirty = true;
    sendView();
  }
  // Same rule as snapshot.content_rect: the world if it has geometry, else the robots.
  function fitContent() {
    const w = S.world;
    const geometry = w && (w.polygons.length || w.circles.length);
    fitRect(geometry ? worldRect() : robotsRect() || [-5, -5, 5, 5]);
  }
  const clampScale = (s) => Math.min(4000, Math.max(0.2, s));

  function resize() {
    const r = canvas.getBoundingClientRect();
    S.dpr = window.devicePixelRatio || 1;
    S.width = Math.max(1, r.width);
    S.height = Math.max(1, r.height);
    canvas.width = Math.round(S.width * S.dpr);
    canvas.height = Math.round(S.height * S.dpr);
    if (S.autoFit) fitContent();
    S.dirty = true;
    sendView();
  }
  new ResizeObserver(resize).observe(canvas);

  // pan, zoom, select
  let drag = null;
  canvas.addEventListener("pointerdown", (e) => {
    drag = { x: e.clientX, y: e.clientY, cx: S.view.cx, cy: S.view.cy, moved: false };
    canvas.setPointerCapture(e.pointerId);
  });
  canvas.addEventListener("pointermove", (e) => {
    if (!drag) return;
    const dx = e.clientX - drag.x, dy = e.clientY - drag.y;
    if (!drag.moved && Math.hypot(dx, dy) < 4) return;
    drag.moved = true;
    canvas.classList.add("dragging");
    S.autoFit = false;
    S.follow = false;
    $("sel-follow").checked = false;
    S.view.cx = drag.cx - dx / S.view.scale;
    S.view.cy = drag.cy + dy / S.view.scale;
    S.dirty = true;
    sendView();
  });
  canvas.addEventListener("pointerup", (e) => {
    if (drag && !drag.moved) {
      const r = canvas.getBoundingClientRect();
      select(pick(e.clientX - r.left, e.clientY - r.top));
    }
    drag = null;
    canvas.classList.remove("dragging");
  });
  canvas.addEventListener("wheel", (e) => {
    e.preventDefault();
    const r = canvas.getBoundingClientRect();
    const px = e.clientX - r.left, py = e.clientY - r.top;
    const x = wx(px), y = wy(py);
    const k = Math.exp(-e.deltaY * (e.deltaMode === 1 ? 0.05 : 0.0015));
    S.view.scale = clampScale(S.view.scale * k);
    S.view.cx = x - (px - S.width / 2) / S.view.scale;
    S.view.cy = y + (py - S.height / 2) / S.view.scale;
    S.autoFit = false;
    S.dirty = true;
    sendView();
  }, { passive: false });

  function pick(px, py) {
    const f = S.frame;
    if (!f || !S.meta) return null;
    const x = wx(px), y = wy(py);
    let best = null, bestD = Infinity;
    for (let i = 0; i < f.n; i++) {
      const d = Math.hypot(f.poses[5 * i] - x, f.poses[5 * i + 1] - y);
      const reach = S.reach[S.meta.robots[i][3]] || 0.1;
      if (d < Math.max(reach * 1.2, 10 / S.view.scale) && d < bestD) {
        best = S.meta.robots[i][0];
        bestD = d;
      }
    }
    return best;
  }

  function select(ns) {
    S.selected = ns;
    $("selected").hidden = !ns;
    for (const li of $("robot-list").children) li.classList.toggle("sel", li.dataset.ns === ns);
    updateSelected();
    S.dirty = true;
    sendView(true);
  }

  // toolbar and keys
  $("fit-world").onclick = () => { S.autoFit = true; fitContent(); };
  $("fit-robots").onclick = () => { S.autoFit = false; fitRect(robotsRect()); };
  for (const k of ["scans", "trails", "labels", "paths"]) {
    $(`show-${k}`).onchange = (e) => { S.opts[k] = e.target.checked; S.dirty = true; sendView(true); };
  }
  $("sel-close").onclick = () => select(null);
  $("sel-follow").onchange = (e) => { S.follow = e.target.checked; if (S.follow) S.autoFit = false; };
  $("filter").oninput = () => renderList();
  $("robot-list").onclick = (e) => {
    const li = e.target.closest("li");
    if (!li) return;
    select(li.dataset.ns);
    const i = S.index.get(li.dataset.ns);
    const p = robotPose(i);
    if (p) {
      S.autoFit = false;
      S.view.cx = p.x;
      S.view.cy = p.y;
      if (S.view.scale < 60) S.view.scale = 120;
      S.dirty = true;
      sendView();
    }
  };
  window.addEventListener("keydown", (e) => {
    if (e.target instanceof HTMLInputElement && e.target.type !== "checkbox") return;
    if (e.key === "Escape") select(null);
    else if (e.key === "f") $("fit-world").click();
    else if (e.key === "r") $("fit-robots").click();
  });

  // ---- side panel -------------------------------------------------------------------------
  function escapeHtml(s) {
    return s.replace(/[&<>"']/g, (c) => `&#${c.charCodeAt(0)};`);
  }
  function renderList() {
    const robots = S.meta ? S.meta.robots : [];
    $("robot-count").textContent = robots.length;
    const byModel = {};
    for (const r of robots) byModel[r[2]] = (byModel[r[2]] || 0) + 1;
    $("model-counts").textContent = Object.keys(byModel).sort()
      .map((m) => `${m} ${byModel[m]}`).join(" · ") || "no robots";
    const q = $("filter").value.trim().toLowerCase();
    const shown = q ? robots.filter((r) => r[0].toLowerCase().includes(q) || r[1].toLowerCase().includes(q)) : robots;
    const limit = 2000;
    $("robot-list").innerHTML = shown.slice(0, limit).map((r) => {
      const label = r[1] === r[0] ? escapeHtml(r[1]) : `${escapeHtml(r[1])} <span class="model">/${escapeHtml(r[0])}</span>`;
      const g = S.nav.get(r[0]);
      const badge = g ? `<span class="nav-state" style="color:${navColor(g.state)}">${escapeHtml(g.state)}</span>` :
        `<span class="nav-state"></span>`;
      return `<li data-ns="${escapeHtml(r[0])}" class="${r[0] === S.selected ? "sel" : ""}">` +
        `<span><span class="swatch" style="background:${robotColor(r)}"></span>${label}${badge}</span>` +
        `<span class="model">${escapeHtml(r[2])}</span></li>`;
    }).join("") + (shown.length > limit ? `<li class="muted">… ${shown.length - limit} more</li>` : "");
  }

  // One robot's navigation badge in the list (a nav message changed its row).
  function updateListItem(ns) {
    const li = $("robot-list").querySelector(`li[data-ns="${CSS.escape(ns)}"]`);
    const badge = li && li.querySelector(".nav-state");
    if (!badge) return;
    const g = S.nav.get(ns);
    badge.textContent = g ? g.state : "";
    badge.style.color = g ? navColor(g.state) : "";
  }

  const fmt = (v, d) => (Number.isFinite(v) ? v.toFixed(d) : "—");
  function updateSelected() {
    const ns = S.selected;
    if (!ns || !S.meta) return;
    const i = S.index.get(ns);
    if (i === undefined) return;
    const row = S.meta.robots[i];
    const p = robotPose(i) || {};
    $("sel-swatch").style.background = robotColor(row);
    $("sel-name").textContent = row[1];
    $("sel-name2").textContent = row[1];
    $("sel-ns").textContent = row[0];
    $("sel-model").textContent = row[2];
    $("sel-x").textContent = `${fmt(p.x, 3)} m`;
    $("sel-y").textContent = `${fmt(p.y, 3)} m`;
    $("sel-yaw").textContent = `${fmt(p.yaw, 3)} rad (${fmt((p.yaw * 180) / Math.PI, 1)}°)`;
    $("sel-v").textContent = `${fmt(p.v, 3)} m/s`;
    $("sel-w").textContent = `${fmt(p.w, 3)} rad/s`;
    const g = S.nav.get(ns);
    $("sel-nav").textContent = g ? navText(g) : "—";
    $("sel-nav").style.color = g ? navColor(g.state) : "";
    const heading = g && g.yaw !== null ? `, ${fmt((g.yaw * 180) / Math.PI, 0)}°` : "";
    $("sel-goal").textContent = g && !g.ended ? `${fmt(g.x, 2)}, ${fmt(g.y, 2)}${heading} ±${fmt(g.tol, 2)} m` : "—";
    const left = g && !g.ended ? navLeft(ns) : null;
    $("sel-left").textContent = left === null ? "—" : `${fmt(left, 2)} m`;
  }

  function updateStatus() {
    const now = performance.now();
    while (drawTimes.length && drawTimes[0] < now - 2000) drawTimes.shift();
    if (drawTimes.length < 2) stats.fps = 0;
    $("conn").classList.toggle("off", !stats.connected);
    const f = S.frame;
    const c = stats.connected ? stats.clock : null;
    $("status-text").textContent = stats.connected
      ? `t ${fmt(stats.simTime, 1)} s · ${stats.robots} robots · ${fmt(stats.fps, 1)} fps${clockText(c)}`
      : "disconnected, retrying…";
    $("status").classList.toggle("behind", !!(c && c.falling_behind && !c.paused));
    $("status").classList.toggle("paused", !!(c && c.paused));
    if (f) {
      const step = f.beam_step > 1 ? `, every ${f.beam_step}${ordinal(f.beam_step)} beam` : "";
      $("perf").textContent =
        `frame ${(stats.bytes / 1024).toFixed(1)} KB · draw ${stats.drawMs.toFixed(1)} ms\n` +
        `scans ${f.scans} robots, ${f.scan_points} points${step}\n` +
        `trails ${f.trails} robots, ${f.trail_points} points\n` +
        `server: build ${fmt(f.stats.build_ms, 1)} ms · skipped ${f.stats.skipped || 0} ticks`;
    }
  }
  // the daemon's clock (fleet clock's real-time factor): achieved / target, falling behind, paused
  const rtfText = (v) => (v >= 100 ? fmt(v, 0) : v >= 10 ? fmt(v, 1) : fmt(v, 2));
  function clockText(c) {
    if (!c) return "";
    if (c.paused) return " · paused";
    if (c.lockstep) return " · lockstep";
    const target = c.target > 0 ? ` / ${+c.target.toFixed(2)}` : " (unpaced)";
    const behind = c.falling_behind ? ` · falling behind ${fmt(c.behind_s, 1)} s` : "";
    return ` · RTF ${rtfText(c.rtf)}${target}${behind}`;
  }
  const ordinal = (n) => (n % 10 === 2 && n !== 12 ? "nd" : n % 10 === 3 && n !== 13 ? "rd" : "th");

  // ---- drawing ----------------------------------------------------------------------------
  const worldCache = { canvas: document.createElement("canvas"), key: "" };

  function drawWorld() {
    const key = `${S.view.cx},${S.view.cy},${S.view.scale},${canvas.width},${canvas.height}`;
    const c = worldCache.canvas;
    if (worldCache.key !== key) {
      worldCache.key = key;
      c.width = canvas.width;
      c.height = canvas.height;
      const g = c.getContext("2d", { alpha: false });
      g.setTransform(S.dpr, 0, 0, S.dpr, 0, 0);
      g.fillStyle = COLORS.bg;
      g.fillRect(0, 0, S.width, S.height);
      const w = S.world;
      if (w && w.bounds) {
        const [x0, y0, x1, y1] = w.bounds;
        g.fillStyle = COLORS.floor;
        g.fillRect(sx(x0), sy(y1), (x1 - x0) * S.view.scale, (y1 - y0) * S.view.scale);
        // grid, clipped to the bounds and to the screen
        const step = gridStep();
        g.beginPath();
        const gx0 = Math.max(x0, wx(0)), gx1 = Math.min(x1, wx(S.width));
        const gy0 = Math.max(y0, wy(S.height)), gy1 = Math.min(y1, wy(0));
        for (let x = Math.ceil(gx0 / step) * step; x <= gx1; x += step) {
          const px = Math.round(sx(x)) + 0.5;
          g.moveTo(px, sy(gy0)); g.lineTo(px, sy(gy1));
        }
        for (let y = Math.ceil(gy0 / step) * step; y <= gy1; y += step) {
          const py = Math.round(sy(y)) + 0.5;
          g.moveTo(sx(gx0), py); g.lineTo(sx(gx1), py);
        }
        g.strokeStyle = COLORS.grid;
        g.lineWidth = 1;
        g.stroke();
        g.strokeStyle = COLORS.bounds;
        g.setLineDash([6, 4]);
        g.strokeRect(sx(x0), sy(y1), (x1 - x0) * S.view.scale, (y1 - y0) * S.view.scale);
        g.setLineDash([]);
      }
      if (w) {
        g.beginPath();
        for (const poly of w.polygons) {
          g.moveTo(sx(poly[0]), sy(poly[1]));
          for (let i = 2; i < poly.length; i += 2) g.lineTo(sx(poly[i]), sy(poly[i + 1]));
          g.closePath();
        }
        g.fillStyle = COLORS.obstacle;
        g.fill();
        g.beginPath();
        for (const [x0, y0, x1, y1] of S.edges) {
          g.moveTo(sx(x0), sy(y0));
          g.lineTo(sx(x1), sy(y1));
        }
        for (const [x, y, r] of w.circles) {
          g.moveTo(sx(x + r), sy(y));
          g.arc(sx(x), sy(y), r * S.view.scale, 0, 2 * Math.PI);
        }
        g.fillStyle = COLORS.obstacle;
        g.fill();
        g.strokeStyle = COLORS.obstacleEdge;
        g.lineWidth = 1;
        g.stroke();
      }
    }
    ctx.setTransform(1, 0, 0, 1, 0, 0);
    ctx.drawImage(c, 0, 0);
    ctx.setTransform(S.dpr, 0, 0, S.dpr, 0, 0);
  }

  // ---- the live map layer (fleet-view --map): /map.png once a second, drawn under the robots ----
  async function fetchMap() {
    try {
      const r = await fetch("/map.png", { cache: "no-store" });
      if (r.status === 404) return false;  // no map layer on this viewer: stop asking
      if (!r.ok) return true;
      const [x0, y0] = (r.headers.get("X-Map-Origin") || "0,0").split(",").map(Number);
      const res = Number(r.headers.get("X-Map-Resolution") || "0.05");
      const img = await createImageBitmap(await r.blob());
      S.map = { img, x0, y0, res };
      stats.mapScans = Number(r.headers.get("X-Map-Scans") || "0");
      S.dirty = true;
    } catch (e) { /* the server is restarting: try again */ }
    return true;
  }
  (async function mapLoop() {
    if (await fetchMap()) setTimeout(mapLoop, 1000);
  })();

  function drawMap() {
    const m = S.map;
    if (!m) return;
    const w = m.img.width * m.res, h = m.img.height * m.res;
    ctx.imageSmoothingEnabled = false;
    ctx.drawImage(m.img, sx(m.x0), sy(m.y0 + h), w * S.view.scale, h * S.view.scale);
  }

  function gridStep() {
    for (const s of [0.1, 0.2, 0.5, 1, 2, 5, 10, 20, 50, 100]) if (s * S.view.scale >= 36) return s;
    return 200;
  }

  function groupPaths() {
    const pal = S.meta.palette;
    return pal.map(() => new Path2D());
  }

  function draw() {
    const t0 = performance.now();
    if (S.follow && S.selected && S.frame) {
      const p = robotPose(S.index.get(S.selected));
      if (p) { S.view.cx = p.x; S.view.cy = p.y; sendView(); }
    }
    drawWorld();
    drawMap();
    const f = S.frame;
    const meta = S.meta;
    if (f && meta) {
      const pal = meta.palette;
      const scale = S.view.scale;
      // trails
      if (S.opts.trails && f.trails) {
        const paths = groupPaths();
        let off = 0;
        for (let k = 0; k < f.trails; k++) {
          const i = f.trailIdx[k], n = f.trailCnt[k];
          const p = paths[meta.robots[i][4] % pal.length];
          for (let j = 0; j < n; j++) {
            const x = sx(f.trailPts[2 * (off + j)]), y = sy(f.trailPts[2 * (off + j) + 1]);
            if (j === 0) p.moveTo(x, y); else p.lineTo(x, y);
          }
          if (n) p.lineTo(sx(f.poses[5 * i]), sy(f.poses[5 * i + 1])); // up to the robot
          off += n;
        }
        ctx.globalAlpha = 0.5;
        ctx.lineWidth = 2;
        ctx.lineJoin = "round";
        ctx.lineCap = "round";
        paths.forEach((p, c) => { ctx.strokeStyle = pal[c]; ctx.stroke(p); });
        ctx.globalAlpha = 1;
      }
      drawPathsAndGoals(f, meta);
      // scans
      if (S.opts.scans && f.scans) {
        const paths = groupPaths();
        const d = scale > 150 ? 2.5 : 2;
        let off = 0;
        for (let k = 0; k < f.scans; k++) {
          const i = f.scanIdx[k], n = f.scanCnt[k];
          const p = paths[meta.robots[i][4] % pal.length];
          for (let j = off; j < off + n; j++) p.rect(sx(f.scanPts[2 * j]) - d / 2, sy(f.scanPts[2 * j + 1]) - d / 2, d, d);
          off += n;
        }
        ctx.globalAlpha = 0.85;
        paths.forEach((p, c) => { ctx.fillStyle = pal[c]; ctx.fill(p); });
        ctx.globalAlpha = 1;
      }
      // robots: footprint filled in the robot's colour, dark outline, white heading mark
      const bodies = groupPaths();
      const dots = groupPaths();
      const heads = new Path2D();
      const xmin = wx(0) - 1, xmax = wx(S.width) + 1, ymin = wy(S.height) - 1, ymax = wy(0) + 1;
      const visible = [];
      for (let i = 0; i < f.n; i++) {
        const x = f.poses[5 * i], y = f.poses[5 * i + 1], yaw = f.poses[5 * i + 2];
        if (x < xmin || x > xmax || y < ymin || y > ymax) continue;
        visible.push(i);
        const row = meta.robots[i];
        const fp = meta.footprints[row[3]];
        const c = Math.cos(yaw), s = Math.sin(yaw);
        const reach = S.reach[row[3]];
        if (reach * scale < 4) { // too small for a shape or a heading: a dot
          const d = Math.max(2.5, 1.6 * reach * scale);
          dots[row[4] % pal.length].rect(sx(x) - d / 2, sy(y) - d / 2, d, d);
          continue;
        }
        const p = bodies[row[4] % pal.length];
        for (let j = 0; j < fp.length; j += 2) {
          const px = sx(x + c * fp[j] - s * fp[j + 1]), py = sy(y + s * fp[j] + c * fp[j + 1]);
          if (j === 0) p.moveTo(px, py); else p.lineTo(px, py);
        }
        p.closePath();
        const nose = reach * 1.45;
        heads.moveTo(sx(x), sy(y));
        heads.lineTo(sx(x + c * nose), sy(y + s * nose));
      }
      ctx.lineWidth = 1;
      ctx.strokeStyle = COLORS.robotEdge;
      bodies.forEach((p, c) => { ctx.fillStyle = pal[c]; ctx.fill(p); ctx.stroke(p); });
      dots.forEach((p, c) => { ctx.fillStyle = pal[c]; ctx.fill(p); });
      ctx.strokeStyle = COLORS.heading;
      ctx.lineWidth = Math.min(3, Math.max(1, scale / 60));
      ctx.lineCap = "round";
      ctx.stroke(heads);
      drawNavRings(visible, f, meta);
      // selection ring
      const sel = S.selected !== null ? S.index.get(S.selected) : undefined;
      if (sel !== undefined) {
        const x = f.poses[5 * sel], y = f.poses[5 * sel + 1];
        const r = S.reach[meta.robots[sel][3]] * scale + 6;
        ctx.beginPath();
        ctx.arc(sx(x), sy(y), r, 0, 2 * Math.PI);
        ctx.strokeStyle = COLORS.select;
        ctx.lineWidth = 1.5;
        ctx.setLineDash([4, 3]);
        ctx.stroke();
        ctx.setLineDash([]);
      }
      // labels: name (and namespace when it differs)
      if (S.opts.labels && (visible.length <= LABEL_MAX || scale >= 60)) {
        ctx.font = "12px system-ui, sans-serif";
        ctx.textBaseline = "bottom";
        for (const i of visible) labelRobot(i, f, meta, scale);
      } else if (sel !== undefined) {
        ctx.font = "12px system-ui, sans-serif";
        ctx.textBaseline = "bottom";
        labelRobot(sel, f, meta, scale);
      }
    }
    drawScaleBar();
    const ms = performance.now() - t0;
    stats.drawMs = stats.drawMs ? 0.9 * stats.drawMs + 0.1 * ms : ms;
  }

  function labelRobot(i, f, meta, scale) {
    const row = meta.robots[i];
    const g = S.nav.get(row[0]);
    const name = row[1] === row[0] ? row[1] : `${row[1]} (${row[0]})`;
    const text = g && g.state !== "driving" ? `${name} · ${g.state}` : name; // the exceptions
    const r = S.reach[row[3]] * scale;
    const x = sx(f.poses[5 * i]) + r + 3, y = sy(f.poses[5 * i + 1]) - r;
    ctx.fillStyle = COLORS.bg;
    ctx.fillText(text, x + 1, y + 1);
    ctx.fillStyle = COLORS.text;
    ctx.fillText(text, x, y);
  }

  // Every navigating robot's path, from the robot on, and its goal: the tolerance circle, a
  // cross at the goal and, if the goal asks for a heading, an arrow. Faint for all (the Paths
  // box hides them), strong and on top for the selected robot.
  function drawPathsAndGoals(f, meta) {
    if (!S.nav.size && !S.paths.size) return;
    const pal = meta.palette;
    const scale = S.view.scale;
    const all = S.opts.paths;
    const lines = groupPaths(), marks = groupPaths();
    const sel = new Path2D();
    let selIndex;
    for (const [ns, p] of S.paths) {
      const i = S.index.get(ns);
      if (i === undefined || (!all && ns !== S.selected)) continue;
      const x = f.poses[5 * i], y = f.poses[5 * i + 1];
      advance(p, x, y);
      const path = ns === S.selected ? sel : lines[meta.robots[i][4] % pal.length];
      // from the robot when it is on its path; from the path's point nearest to it when it
      // is off it (making way, going round something): no line through a wall to get there
      if (p.off <= PATH_OFF_M) path.moveTo(sx(x), sy(y));
      else path.moveTo(sx(p.px), sy(p.py));
      for (let j = p.k + 1; j < p.n; j++) path.lineTo(sx(p.pts[2 * j]), sy(p.pts[2 * j + 1]));
      if (ns === S.selected) selIndex = i;
    }
    for (const [ns, g] of S.nav) {
      const i = S.index.get(ns);
      if (g.ended || i === undefined || (!all && ns !== S.selected)) continue;
      goalMark(ns === S.selected ? sel : marks[meta.robots[i][4] % pal.length], g, scale);
      if (ns === S.selected) selIndex = i;
    }
    ctx.lineJoin = "round";
    ctx.lineCap = "round";
    ctx.lineWidth = 1.5;
    ctx.globalAlpha = S.paths.size <= PATHS_FEW ? 0.55 : 0.3;
    lines.forEach((p, c) => { ctx.strokeStyle = pal[c]; ctx.stroke(p); });
    marks.forEach((p, c) => { ctx.strokeStyle = pal[c]; ctx.stroke(p); });
    ctx.globalAlpha = 1;
    if (selIndex !== undefined) {
      ctx.lineWidth = 4;
      ctx.strokeStyle = COLORS.bg;
      ctx.stroke(sel);
      ctx.lineWidth = 2;
      ctx.strokeStyle = robotColor(meta.robots[selIndex]);
      ctx.stroke(sel);
    }
  }

  function goalMark(m, g, scale) {
    const cx = sx(g.x), cy = sy(g.y);
    const r = Math.max(g.tol * scale, 3);
    m.moveTo(cx + r, cy);
    m.arc(cx, cy, r, 0, 2 * Math.PI);
    const c = Math.max(3, Math.min(7, r * 0.5));
    m.moveTo(cx - c, cy); m.lineTo(cx + c, cy);
    m.moveTo(cx, cy - c); m.lineTo(cx, cy + c);
    if (g.yaw !== null) {
      const len = Math.max(r + 8, 16), a = -g.yaw; // screen y points down
      const ex = cx + Math.cos(a) * len, ey = cy + Math.sin(a) * len;
      m.moveTo(cx, cy); m.lineTo(ex, ey);
      for (const s of [-0.45, 0.45]) {
        m.moveTo(ex, ey);
        m.lineTo(ex - 7 * Math.cos(a + s), ey - 7 * Math.sin(a + s));
      }
    }
  }

  // A ring in the state's colour round each robot in view that navigates but is not simply
  // driving (planning, waiting, yielding, blocked, overridden), and a fading flash round one
  // whose goal just ended.
  function drawNavRings(visible, f, meta) {
    if (!S.nav.size) return;
    const scale = S.view.scale, now = performance.now();
    const rings = new Map();
    let flashing = false;
    for (const i of visible) {
      const g = S.nav.get(meta.robots[i][0]);
      if (!g) continue;
      const x = sx(f.poses[5 * i]), y = sy(f.poses[5 * i + 1]);
      const r = Math.max(S.reach[meta.robots[i][3]] * scale, 2) + 4;
      if (g.ended) {
        const t = (now - g.endedAt) / FLASH_MS;
        if (t >= 1) continue;
        flashing = true;
        ctx.globalAlpha = 1 - t;
        ctx.strokeStyle = navColor(g.state);
        ctx.lineWidth = 3;
        ctx.beginPath();
        ctx.arc(x, y, r + 16 * t, 0, 2 * Math.PI);
        ctx.stroke();
        continue;
      }
      if (!NAV_RING.has(g.state)) continue;
      const col = navColor(g.state);
      let p = rings.get(col);
      if (!p) rings.set(col, (p = new Path2D()));
      p.moveTo(x + r, y);
      p.arc(x, y, r, 0, 2 * Math.PI);
    }
    ctx.globalAlpha = 1;
    ctx.lineWidth = 2;
    for (const [col, p] of rings) { ctx.strokeStyle = col; ctx.stroke(p); }
    if (flashing) S.dirty = true; // keep animating
  }

  function drawScaleBar() {
    const step = gridStep();
    const len = step * S.view.scale;
    const x = 14, y = S.height - 16;
    ctx.strokeStyle = COLORS.text;
    ctx.lineWidth = 2;
    ctx.beginPath();
    ctx.moveTo(x, y - 4); ctx.lineTo(x, y); ctx.lineTo(x + len, y); ctx.lineTo(x + len, y - 4);
    ctx.stroke();
    ctx.fillStyle = COLORS.muted;
    ctx.font = "11px system-ui, sans-serif";
    ctx.textBaseline = "middle";
    ctx.fillText(`${step} m`, x + len + 6, y - 2);
  }

  // ---- loop -------------------------------------------------------------------------------
  function loop(now) {
    requestAnimationFrame(loop);
    const f = S.frame;
    if (f && S.autoFit && !(S.world && (S.world.polygons.length || S.world.circles.length))) {
      // an obstacle-free world: keep the robots framed until the user takes over
      const r = robotsRect();
      if (r && (!S.fitted || r.some((v, k) => Math.abs(v - S.fitted[k]) > 0.5))) {
        S.fitted = r;
        fitRect(r);
      }
    }
    if (!S.dirty) return;
    S.dirty = false;
    draw();
    if (f && f.seq !== S.drawnSeq) {
      S.drawnSeq = f.seq;
      stats.frames += 1;
      stats.seq = f.seq;
      stats.simTime = f.t;
      stats.scans = f.scans;
      stats.scanPoints = f.scan_points;
      stats.trails = f.trails;
      stats.trailPoints = f.trail_points;
      stats.beamStep = f.beam_step;
      stats.skipped = f.stats.skipped || 0;
      drawTimes.push(now);
      while (drawTimes.length && drawTimes[0] < now - 2000) drawTimes.shift();
      stats.fps = drawTimes.length > 1 ? (1000 * (drawTimes.length - 1)) / (now - drawTimes[0]) : 0;
      updateSelected();
    }
  }
  setInterval(updateStatus, 250);
  resize();
  connect();
  requestAnimationFrame(loop);
})();
