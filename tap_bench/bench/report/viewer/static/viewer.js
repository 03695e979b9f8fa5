/* tap-bench replay viewer: plain JavaScript, Canvas and SVG; no network, no server.
 *
 * data/index.js calls TAPVIEW.index(doc): the episode list, the road maps per env and the
 * run's facts. data/<chunk>.js calls TAPVIEW.chunk(name, episodes) when a chunk is loaded
 * (every policy of one env and seed). See tap_bench/bench/report/viewer/data.py for the documents.
 *
 * State lives in TAPVIEW.state and in the URL hash (#ep=<id>&b=<policy>&t=<s> and filters
 * f_env, f_policy, f_label, f_sdl, f_crash, f_novel), so a link opens a given replay.
 */
"use strict";

const TAPVIEW = (() => {
  const MISSING = -32768;
  const HZ = 10;
  const SVGNS = "http://www.w3.org/2000/svg";
  const state = {
    index: null, episodes: new Map(), chunks: new Map(), pending: new Map(),
    a: null, b: null, bPolicy: null, t: 0, playing: false, speed: 1, zoom: 8,
    filters: {env: "", policy: "", label: "", sdl: "", crash: "", novel: ""},
    decoded: new Map(), frames: 0,
  };
  const $ = (id) => document.getElementById(id);

  // -- data ---------------------------------------------------------------------------
  function int16(b64) {
    const s = atob(b64);
    const bytes = new Uint8Array(s.length);
    for (let i = 0; i < s.length; i++) bytes[i] = s.charCodeAt(i);
    return new Int16Array(bytes.buffer);
  }

  function decode(doc) {
    if (state.decoded.has(doc.id)) return state.decoded.get(doc.id);
    const q = doc.q;
    const tracks = doc.tracks.map((tr) => {
      const a = int16(tr.xyh);
      const n = tr.n;
      return {id: tr.id, ego: tr.ego, type: tr.type, len: tr.len, wid: tr.wid, s0: tr.s0, n,
              x: a.subarray(0, n), y: a.subarray(n, 2 * n), h: a.subarray(2 * n, 3 * n)};
    });
    let measures = null;
    if (doc.measures) {
      const m = doc.measures;
      measures = {s0: m.s0, n: m.n, scored_from: m.scored_from};
      for (const key of ["speed", "gap", "headway", "ttc"]) measures[key] = int16(m[key]);
    }
    const out = {doc, q, origin: doc.origin, tracks, measures,
                 ego: tracks.find((t) => t.ego) || tracks[0],
                 duration: (doc.n - 1) / HZ};
    state.decoded.set(doc.id, out);
    return out;
  }

  function pose(ep, tr, t) {
    // position [m] and heading [rad] of a track at time t (s since the episode start)
    const f = t * HZ - tr.s0;
    if (f < 0 || f > tr.n - 1) return null;
    const i = Math.floor(f);
    const j = Math.min(i + 1, tr.n - 1);
    if (tr.x[i] === MISSING) return null;
    const w = tr.x[j] === MISSING ? 0 : f - i;
    const q = ep.q;
    const x = (tr.x[i] + w * (tr.x[j] - tr.x[i])) * q + ep.origin[0];
    const y = (tr.y[i] + w * (tr.y[j] - tr.y[i])) * q + ep.origin[1];
    const h0 = tr.h[i] * Math.PI / 32767;
    let dh = tr.h[j] * Math.PI / 32767 - h0;
    dh = Math.atan2(Math.sin(dh), Math.cos(dh));
    return {x, y, h: h0 + w * dh};
  }

  function loadChunk(name) {
    if (state.chunks.has(name)) return Promise.resolve(state.chunks.get(name));
    if (state.pending.has(name)) return state.pending.get(name).promise;
    let resolve, reject;
    const promise = new Promise((res, rej) => { resolve = res; reject = rej; });
    state.pending.set(name, {promise, resolve, reject});
    const el = document.createElement("script");
    el.src = "data/" + encodeURIComponent(name) + ".js";
    el.onerror = () => reject(new Error("cannot load data/" + name + ".js"));
    document.body.appendChild(el);
    return promise;
  }

  function chunk(name, docs) {
    for (const d of docs) state.episodes.set(d.id, d);
    state.chunks.set(name, docs);
    const p = state.pending.get(name);
    if (p) { p.resolve(docs); state.pending.delete(name); }
  }

  // -- labels and colours -------------------------------------------------------------
  const BASE_COLOURS = [
    [/Left Merge/, "#4c6ef5"], [/Right Merge/, "#f08c00"], [/Left Turn/, "#12b886"],
    [/Right Turn/, "#ae3ec9"], [/Straight/, "#adb5bd"], [/Accelerate/, "#37b24d"],
    [/Decelerate/, "#f03e3e"], [/Stopped/, "#343a40"], [/Maintain/, "#ced4da"],
    [/Following/, "#74c0fc"], [/Free Driving/, "#e9ecef"], [/Cut-in/, "#e8590c"],
    [/Cut-out/, "#fab005"], [/Overtaking/, "#20c997"], [/Being Overtaken/, "#9775fa"],
    [/Lead Braking/, "#c92a2a"],
  ];
  function colour(label) {
    for (const [re, c] of BASE_COLOURS) if (re.test(label)) return c;
    let h = 0;
    for (const ch of label) h = (h * 31 + ch.charCodeAt(0)) % 360;
    return `hsl(${h},55%,60%)`;
  }
  function darkText(c) { return !["#343a40", "#c92a2a", "#4c6ef5", "#ae3ec9", "#f03e3e"].includes(c); }

  function labelAt(runs, t) {
    if (!runs) return null;
    for (const r of runs) if (t >= r[0] - 1e-6 && t < r[1] - 1e-6) return r;
    return null;
  }

  // -- the list -----------------------------------------------------------------------
  function matches(e) {
    const f = state.filters;
    if (f.env && e.env !== f.env) return false;
    if (f.policy && e.policy !== f.policy) return false;
    if (f.sdl && e.sdl !== f.sdl && e.interaction !== f.sdl) return false;
    if (f.label) {
      const text = (e.sdl + " " + e.interaction).toLowerCase();
      if (!text.includes(f.label.toLowerCase())) return false;
    }
    if (f.crash === "yes" && !e.crashed) return false;
    if (f.crash === "no" && e.crashed) return false;
    if (f.novel === "yes" && !e.novel.length) return false;
    if (f.novel === "no" && e.novel.length) return false;
    return true;
  }

  function renderList() {
    const list = $("episode-list");
    list.textContent = "";
    const shown = state.index.episodes.filter(matches);
    const max = 400;
    for (const e of shown.slice(0, max)) {
      const li = document.createElement("li");
      li.dataset.id = e.id;
      if (!e.ok || !e.replay) li.className = "failed";
      if (state.a && state.a.doc.id === e.id) li.classList.add("active");
      const head = document.createElement("span");
      // the name the index gives (a real scene's scenario id, else env and seed)
      head.textContent = `${e.name} · ${e.policy}`;
      li.appendChild(head);
      if (e.crashed) li.appendChild(badge("crash", "crash"));
      if (e.novel.length) {
        const b = badge("novel", "novel");
        b.title = "label never shown by: " + e.novel.join(", ");
        li.appendChild(b);
      }
      const sdl = document.createElement("span");
      sdl.className = "sdl";
      sdl.textContent = e.ok ? (e.sdl || "(no label)") : "failed: " + e.error;
      li.appendChild(sdl);
      if (e.ok && e.replay) li.addEventListener("click", () => openEpisode(e.id, null));
      list.appendChild(li);
    }
    const total = state.index.episodes.length;
    $("list-count").textContent = `${shown.length} of ${total} episodes` +
      (shown.length > max ? ` (first ${max} listed; narrow the filters)` : "");
  }

  function badge(cls, text) {
    const b = document.createElement("span");
    b.className = "badge " + cls;
    b.textContent = text;
    return b;
  }

  function fillSelect(sel, values) {
    for (const v of values) {
      const o = document.createElement("option");
      o.value = v; o.textContent = v;
      sel.appendChild(o);
    }
  }

  // -- opening episodes ---------------------------------------------------------------
  function entry(id) { return state.index.episodes.find((e) => e.id === id); }

  function partners(e) {
    return state.index.episodes.filter((o) => o.env === e.env && o.seed === e.seed &&
                                        o.id !== e.id && o.ok && o.replay);
  }

  async function openEpisode(id, bPolicy, t) {
    const e = entry(id);
    if (!e) { showMessage(`no episode ${id} in this viewer`); return; }
    const docs = await loadChunk(e.chunk);
    const doc = docs.find((d) => d.id === id);
    state.a = decode(doc);
    state.a.entry = e;
    const others = partners(e);
    const sel = $("b-policy");
    sel.textContent = "";
    fillSelect(sel, ["(none)", ...others.map((o) => o.policy)]);
    let want = bPolicy ?? state.bPolicy;
    if (!others.some((o) => o.policy === want)) {
      const ref = state.index.run.reference;
      want = others.some((o) => o.policy === ref) ? ref : (others[0] || {}).policy;
    }
    if (bPolicy === "(none)") want = "(none)";
    sel.value = want || "(none)";
    setB(sel.value, docs);
    state.t = Math.min(t || 0, maxDuration());
    state.playing = false;
    build();
    renderList();
    draw();
    updateHash();
  }

  function setB(policy, docs) {
    state.bPolicy = policy;
    const e = state.a.entry;
    const o = partners(e).find((p) => p.policy === policy);
    if (!o) { state.b = null; return; }
    const doc = (docs || state.chunks.get(o.chunk)).find((d) => d.id === o.id);
    state.b = decode(doc);
    state.b.entry = o;
  }

  function maxDuration() {
    return Math.max(state.a ? state.a.duration : 0, state.b ? state.b.duration : 0);
  }

  function showMessage(text) {
    const pa = $("pane-a");
    pa.textContent = "";
    const p = document.createElement("p");
    p.className = "empty";
    p.textContent = text;
    pa.appendChild(p);
    $("pane-b").textContent = "";
  }

  // -- panes --------------------------------------------------------------------------
  function build() {
    $("panes").classList.toggle("single", !state.b);
    buildPane($("pane-a"), state.a, "A");
    if (state.b) buildPane($("pane-b"), state.b, "B");
    else $("pane-b").textContent = "";
    const scrub = $("scrub");
    scrub.max = maxDuration().toFixed(1);
    scrub.value = state.t.toFixed(1);
  }

  function fmt(v, digits, unit) {
    return v === null || v === undefined ? "–" : `${v.toFixed(digits)} ${unit}`;
  }

  function buildPane(root, ep, tag) {
    root.textContent = "";
    const e = ep.entry;
    const h = document.createElement("h3");
    h.textContent = `${tag}: ${e.policy} — ${e.name}`;
    if (e.crashed) h.appendChild(badge("crash", `crash at ${ep.doc.crash_t ?? "?"} s`));
    if (e.novel.length) h.appendChild(badge("novel", "novel label"));
    root.appendChild(h);
    const facts = document.createElement("p");
    facts.className = "facts";
    // every measure of the run, as its entry says: label, unit, decimals (a rate is 0 or 1
    // per episode and shown as yes / no)
    const values = (state.index.run.measures || []).map((m) => {
      const v = (e.measures || {})[m.name];
      if (m.kind === "rate") {  // the episode's own value: the event happened or not
        return `${m.name}: ${v === null || v === undefined ? "–" : v > 0 ? "yes" : "no"}`;
      }
      return `${m.label} ${fmt(v, m.decimals, m.display_unit)}`;
    });
    facts.textContent = [`SDL: ${e.sdl || "(none)"}`, ...values].join(" · ");
    root.appendChild(facts);
    const canvas = document.createElement("canvas");
    canvas.width = 640; canvas.height = 300;
    canvas.setAttribute("aria-label", `top-down view of ${tag}`);
    root.appendChild(canvas);
    const now = document.createElement("p");
    now.className = "now";
    root.appendChild(now);
    ep.view = {root, canvas, now, tag};
    ep.focus = ep.focus || ep.ego.id;
    const who = document.createElement("p");
    who.className = "note who";
    root.appendChild(who);
    ep.view.who = who;
    ep.view.timeline = timeline(ep.doc.labels[ep.focus] || {}, maxDuration(),
                                ep.focus === ep.ego.id ? ep.doc.crash_t : null);
    who.textContent = `label timelines of ${ep.focus === ep.ego.id ? "the ego" : "track " +
      ep.focus}` + (Object.keys(ep.doc.labels).length > 1 ? " (click a vehicle for its own)"
                    : "");
    root.appendChild(ep.view.timeline.svg);
    canvas.addEventListener("click", (ev) => focusAt(ep, ev));
    if (ep.measures) {
      ep.view.chart = chart(ep, maxDuration());
      root.appendChild(ep.view.chart.svg);
    }
  }

  function svg(tag, attrs, parent) {
    const el = document.createElementNS(SVGNS, tag);
    for (const [k, v] of Object.entries(attrs || {})) el.setAttribute(k, v);
    if (parent) parent.appendChild(el);
    return el;
  }

  const LEFT = 96, RIGHT = 20, WIDTH = 640;
  function xOf(t, duration) { return LEFT + (WIDTH - LEFT - RIGHT) * t / Math.max(duration, 0.1); }

  function timeline(labels, duration, crashT) {
    const axes = ["lateral", "longitudinal"];
    if (labels.interaction || state.hasInteraction) axes.push("interaction");
    const rowH = 22;
    const height = axes.length * (rowH + 4) + 22;
    const root = svg("svg", {viewBox: `0 0 ${WIDTH} ${height}`, width: "100%",
                             class: "timeline", role: "img",
                             "aria-label": "label timelines"});
    axes.forEach((axis, k) => {
      const y = k * (rowH + 4) + 2;
      const name = svg("text", {x: 4, y: y + 15}, root);
      name.textContent = axis;
      const runs = labels[axis] || [];
      if (!runs.length) {
        const none = svg("text", {x: LEFT + 4, y: y + 15, class: "missing"}, root);
        none.textContent = axis === "interaction" ? "(no interaction labels)" : "(no label)";
      }
      for (const r of runs) {
        const x0 = xOf(r[0], duration), x1 = xOf(r[1], duration);
        const c = colour(r[2]);
        const g = svg("g", {class: "run", "data-axis": axis, "data-label": r[2]}, root);
        svg("rect", {x: x0, y, width: Math.max(x1 - x0 - 1, 1), height: rowH, fill: c,
                     rx: 2}, g);
        const title = svg("title", {}, g);
        title.textContent = `${axis}: ${r[2]}${r[3] ? " (track " + r[3] + ")" : ""}, ` +
          `${r[0].toFixed(1)}–${r[1].toFixed(1)} s`;
        const txt = r[2] + (r[3] ? ` (${r[3]})` : "");
        const room = (x1 - x0 - 6) / 6.2;  // characters that fit at 11 px
        if (room >= 4) {
          const label = svg("text", {x: x0 + 3, y: y + 15, fill: darkText(c) ? "#111" : "#fff"},
                            g);
          label.textContent = txt.length <= room ? txt : txt.slice(0, Math.floor(room) - 1) + "…";
          label.style.fill = darkText(c) ? "#111" : "#fff";
        }
      }
    });
    const axisY = axes.length * (rowH + 4) + 2;
    timeAxis(root, duration, axisY);
    if (crashT !== null && crashT !== undefined) {
      svg("line", {x1: xOf(crashT, duration), x2: xOf(crashT, duration), y1: 0, y2: axisY,
                   class: "crash-line"}, root);
    }
    const playhead = svg("line", {x1: LEFT, x2: LEFT, y1: 0, y2: axisY, class: "playhead"},
                         root);
    return {svg: root, playhead, duration, axes};
  }

  function timeAxis(root, duration, y) {
    const g = svg("g", {class: "axis"}, root);
    svg("line", {x1: LEFT, x2: WIDTH - RIGHT, y1: y, y2: y, stroke: "#888"}, g);
    const step = duration > 40 ? 10 : duration > 12 ? 5 : duration > 5 ? 2 : 1;
    for (let s = 0; s <= duration + 1e-6; s += step) {
      const x = xOf(s, duration);
      svg("line", {x1: x, x2: x, y1: y, y2: y + 4, stroke: "#888"}, g);
      const tx = svg("text", {x, y: y + 15, "text-anchor": "middle"}, g);
      tx.textContent = `${s} s`;
    }
  }

  const CHARTS = [
    {key: "speed", name: "speed", unit: "m/s", digits: 1},
    {key: "headway", name: "headway", unit: "s", digits: 2, cap: 10},
    {key: "ttc", name: "TTC", unit: "s", digits: 2, cap: 10},
  ];

  function series(ep, key) {
    const m = ep.measures;
    const out = [];
    for (let i = 0; i < m.n; i++) {
      const v = m[key][i];
      out.push(v === MISSING ? null : v / 100);
    }
    return out;
  }

  function chart(ep, duration) {
    const h = 58, gap = 10;
    const height = CHARTS.length * (h + gap) + 20;
    const root = svg("svg", {viewBox: `0 0 ${WIDTH} ${height}`, width: "100%", class: "chart",
                             role: "img", "aria-label": "safety measures over time"});
    const m = ep.measures;
    CHARTS.forEach((c, k) => {
      const y0 = k * (h + gap) + 4;
      const values = series(ep, c.key);
      const finite = values.filter((v) => v !== null);
      const top = c.cap ? c.cap : Math.max(1, ...finite) * 1.1;
      const yOf = (v) => y0 + h - h * Math.min(v, top) / top;
      svg("rect", {x: LEFT, y: y0, width: WIDTH - LEFT - RIGHT, height: h, fill: "#fbfbfb",
                   stroke: "#ddd"}, root);
      if (m.scored_from !== null && m.scored_from > 0) {
        svg("rect", {x: LEFT, y: y0, width: xOf(m.scored_from, duration) - LEFT, height: h,
                     class: "burn-in"}, root);
      }
      const name = svg("text", {x: 4, y: y0 + 14}, root);
      name.textContent = c.name;
      const unit = svg("text", {x: 4, y: y0 + 28}, root);
      unit.textContent = `[${c.unit}]`;
      for (const v of [0, top]) {
        const tick = svg("text", {x: LEFT - 4, y: yOf(v) + 4, "text-anchor": "end"}, root);
        tick.textContent = c.cap && v === top ? `${top}+` : (v === 0 ? "0" : v.toFixed(0));
      }
      let path = "";
      let pen = false;
      values.forEach((v, i) => {
        if (v === null) { pen = false; return; }
        const x = xOf((m.s0 + i) / HZ, duration);
        path += `${pen ? "L" : "M"}${x.toFixed(1)},${yOf(v).toFixed(1)}`;
        pen = true;
      });
      svg("path", {d: path || "M0,0", fill: "none", stroke: "#1c7ed6", "stroke-width": 1.5,
                   class: "series", "data-key": c.key}, root);
      if (!finite.length) {
        const none = svg("text", {x: LEFT + 6, y: y0 + h / 2 + 4}, root);
        none.textContent = "no vehicle ahead";
      }
    });
    const axisY = CHARTS.length * (h + gap) - gap + 4;
    timeAxis(root, duration, axisY);
    if (ep.doc.crash_t !== null) {
      svg("line", {x1: xOf(ep.doc.crash_t, duration), x2: xOf(ep.doc.crash_t, duration),
                   y1: 0, y2: axisY, class: "crash-line"}, root);
    }
    const playhead = svg("line", {x1: LEFT, x2: LEFT, y1: 0, y2: axisY, class: "playhead"},
                         root);
    return {svg: root, playhead, duration};
  }

  // -- drawing ------------------------------------------------------------------------
  function mapOf(ep) {
    if (ep.doc.map) return ep.doc.map;
    const name = ep.entry.map;
    return name ? state.index.maps[name] || [] : [];
  }

  function sceneBox(ep) {
    let x0 = Infinity, y0 = Infinity, x1 = -Infinity, y1 = -Infinity;
    for (const tr of ep.tracks) {
      for (let i = 0; i < tr.n; i++) {
        if (tr.x[i] === MISSING) continue;
        const x = tr.x[i] * ep.q + ep.origin[0], y = tr.y[i] * ep.q + ep.origin[1];
        x0 = Math.min(x0, x); x1 = Math.max(x1, x); y0 = Math.min(y0, y); y1 = Math.max(y1, y);
      }
    }
    return [x0, y0, x1, y1];
  }

  function drawScene(ep, t) {
    const canvas = ep.view.canvas;
    const ctx = canvas.getContext("2d");
    const W = canvas.width, H = canvas.height;
    ctx.setTransform(1, 0, 0, 1, 0, 0);
    ctx.fillStyle = "#e9ede6";
    ctx.fillRect(0, 0, W, H);
    const tc = Math.min(t, ep.duration);
    let scale = state.zoom, cx, cy;
    if (scale > 0) {
      const p = pose(ep, ep.ego, tc) || lastPose(ep, ep.ego);
      cx = p ? p.x : ep.origin[0]; cy = p ? p.y : ep.origin[1];
    } else {
      const b = ep.box || (ep.box = sceneBox(ep));
      cx = (b[0] + b[2]) / 2; cy = (b[1] + b[3]) / 2;
      scale = Math.min(W / (b[2] - b[0] + 20), H / (b[3] - b[1] + 20));
    }
    ep.view.transform = [scale, cx, cy, W, H];
    // world (y to the left, i.e. up on screen) to canvas pixels
    ctx.setTransform(scale, 0, 0, -scale, W / 2 - scale * cx, H / 2 + scale * cy);
    drawMap(ctx, mapOf(ep), scale);
    drawSignals(ctx, ep, tc, scale);
    // the egos' whole paths: the other pane's (on recorded scenes the human, beside the
    // policy that drove in its place) wide and grey under this pane's
    const other = ep === state.a ? state.b : state.a;
    if (other) drawPath(ctx, other, other.ego, "rgba(60,60,60,0.35)", 1.2);
    drawPath(ctx, ep, ep.ego, "rgba(224,49,49,0.7)", 0.35);
    for (const tr of ep.tracks) {
      if (tr.ego) continue;
      const p = pose(ep, tr, tc);
      if (p) drawVehicle(ctx, tr, p, tr.id === ep.focus ? "#f59f00" : "#3b6fb6");
    }
    // the other pane's ego as a ghost (same env and seed: on recorded scenes, the human
    // beside the policy that drove in its place)
    if (other) {
      const pg = pose(other, other.ego, Math.min(tc, other.duration));
      if (pg) drawGhost(ctx, other.ego, pg);
    }
    const pe = pose(ep, ep.ego, tc) || lastPose(ep, ep.ego);
    const crashed = ep.doc.crash_t !== null && tc >= ep.doc.crash_t - 1e-6;
    if (pe) drawVehicle(ctx, ep.ego, pe, crashed ? "#7a0000" : "#e03131", true);
    ctx.setTransform(1, 0, 0, 1, 0, 0);
    ctx.font = "12px system-ui, sans-serif";
    ctx.fillStyle = "#222";
    ctx.fillText(`t = ${tc.toFixed(1)} s`, 8, 16);
    if (other) {
      ctx.fillStyle = "#555";
      ctx.fillText(`grey: ${other.entry.policy}'s path`, 8, 32);
      ctx.fillStyle = "#222";
    }
    const scaleM = 10 ** Math.floor(Math.log10(120 / scale));
    ctx.fillRect(8, H - 12, scaleM * scale, 3);
    ctx.fillText(`${scaleM} m`, 12 + scaleM * scale, H - 8);
    if (t > ep.duration + 1e-6) {
      ctx.fillStyle = "rgba(255,255,255,0.75)";
      ctx.fillRect(W / 2 - 150, 8, 300, 24);
      ctx.fillStyle = "#c92a2a";
      ctx.fillText(`episode ended at ${ep.duration.toFixed(1)} s` +
                   (ep.doc.crash_t !== null ? " (crash)" : ""), W / 2 - 140, 25);
    }
  }

  function lastPose(ep, tr) {
    for (let i = tr.n - 1; i >= 0; i--) {
      if (tr.x[i] !== MISSING) return pose(ep, tr, (tr.s0 + i) / HZ);
    }
    return null;
  }

  function drawMap(ctx, features, scale) {
    ctx.lineCap = "butt";
    ctx.lineJoin = "round";
    const hasWidth = features.some((f) => f[0] === "lane" && f[2]);
    for (const [kind, style, width, pts] of features) {
      ctx.beginPath();
      ctx.moveTo(pts[0], pts[1]);
      for (let i = 2; i < pts.length; i += 2) ctx.lineTo(pts[i], pts[i + 1]);
      ctx.setLineDash([]);
      if (kind === "lane") {
        if (width) { ctx.strokeStyle = "#b6bcc2"; ctx.lineWidth = width; }
        else { ctx.strokeStyle = "#c5cad0"; ctx.lineWidth = 1.2 / scale; }
      } else if (kind === "road_line") {
        ctx.strokeStyle = "#ffffff";
        ctx.lineWidth = Math.max(0.15, 1.5 / scale);
        if (style === "dashed") ctx.setLineDash([3, 6]);
        if (!hasWidth) ctx.strokeStyle = "#8a9099";  // no lane surface: grey on the ground
      } else if (kind === "road_edge") {
        ctx.strokeStyle = "#343a40"; ctx.lineWidth = 2 / scale;
      } else {
        ctx.strokeStyle = "#a5d8ff"; ctx.lineWidth = 1.5 / scale;
      }
      ctx.stroke();
    }
    ctx.setLineDash([]);
  }

  function drawVehicle(ctx, tr, p, fill, ego) {
    ctx.save();
    ctx.translate(p.x, p.y);
    ctx.rotate(p.h);
    ctx.fillStyle = fill;
    if (tr.type === "p") {
      ctx.beginPath();
      ctx.arc(0, 0, 0.5, 0, 2 * Math.PI);
      ctx.fillStyle = "#2b8a3e";
      ctx.fill();
    } else {
      ctx.fillRect(-tr.len / 2, -tr.wid / 2, tr.len, tr.wid);
      ctx.fillStyle = "rgba(255,255,255,0.7)";  // the windscreen shows the heading
      ctx.fillRect(tr.len / 2 - 1.2, -tr.wid / 2 + 0.2, 0.5, tr.wid - 0.4);
      if (ego) {
        ctx.strokeStyle = "#000"; ctx.lineWidth = 0.25;
        ctx.strokeRect(-tr.len / 2, -tr.wid / 2, tr.len, tr.wid);
      }
    }
    ctx.restore();
  }

  const SIGNAL_FILL = {r: "#e03131", y: "#f5c400", g: "#2f9e44", u: "#868e96"};

  function signalsAt(ep, t) {
    // the state letter of each stop point at time t (r red, y yellow, g green, u unknown)
    const sig = ep.doc.signals;
    if (!sig || !sig.states.length) return "";
    const k = Math.max(0, Math.min(Math.round(t * HZ), sig.states.length - 1));
    return sig.states[k];
  }

  function drawSignals(ctx, ep, t, scale) {
    // a WOMD scene's traffic signals: a disc at each stop point, coloured by its state
    const sig = ep.doc.signals;
    const now = signalsAt(ep, t);
    if (!now) return;
    const r = Math.max(0.9, 4 / scale);
    ctx.setLineDash([]);
    ctx.lineWidth = Math.max(0.1, 1 / scale);
    ctx.strokeStyle = "#222";
    sig.points.forEach(([x, y], j) => {
      ctx.beginPath();
      ctx.arc(x, y, r, 0, 2 * Math.PI);
      ctx.fillStyle = SIGNAL_FILL[now[j]] || SIGNAL_FILL.u;
      ctx.fill();
      ctx.stroke();
    });
  }

  function drawPath(ctx, ep, tr, color, width) {
    // the track's whole recorded path, a line ``width`` metres wide (gaps left open)
    ctx.save();
    ctx.strokeStyle = color;
    ctx.lineWidth = width;
    ctx.lineCap = "round";
    ctx.lineJoin = "round";
    ctx.beginPath();
    let pen = false;
    for (let i = 0; i < tr.n; i++) {
      if (tr.x[i] === MISSING) { pen = false; continue; }
      const x = tr.x[i] * ep.q + ep.origin[0], y = tr.y[i] * ep.q + ep.origin[1];
      if (pen) ctx.lineTo(x, y); else ctx.moveTo(x, y);
      pen = true;
    }
    ctx.stroke();
    ctx.restore();
  }

  function drawGhost(ctx, tr, p) {
    // a dashed outline where the other pane's ego is at this time
    ctx.save();
    ctx.translate(p.x, p.y);
    ctx.rotate(p.h);
    ctx.setLineDash([0.6, 0.4]);
    ctx.strokeStyle = "#000";
    ctx.lineWidth = 0.2;
    ctx.strokeRect(-tr.len / 2, -tr.wid / 2, tr.len, tr.wid);
    ctx.restore();
  }

  function focusAt(ep, ev) {
    // the vehicle under a click becomes the one whose labels are shown
    const r = ep.view.canvas.getBoundingClientRect();
    const px = (ev.clientX - r.left) * ep.view.canvas.width / r.width;
    const py = (ev.clientY - r.top) * ep.view.canvas.height / r.height;
    const [s, cx, cy, W, H] = ep.view.transform;
    const x = cx + (px - W / 2) / s, y = cy - (py - H / 2) / s;
    let best = null, dist = 4;
    for (const tr of ep.tracks) {
      const p = pose(ep, tr, Math.min(state.t, ep.duration));
      if (!p || !ep.doc.labels[tr.id]) continue;
      const d = Math.hypot(p.x - x, p.y - y);
      if (d < dist) { best = tr; dist = d; }
    }
    if (!best) return;
    ep.focus = best.id;
    const old = ep.view.timeline.svg;
    ep.view.timeline = timeline(ep.doc.labels[ep.focus] || {}, maxDuration(),
                                ep.focus === ep.ego.id ? ep.doc.crash_t : null);
    old.replaceWith(ep.view.timeline.svg);
    ep.view.who.textContent = `label timelines of ${ep.focus === ep.ego.id ? "the ego"
      : "track " + ep.focus} (click a vehicle for its own)`;
    draw();
  }

  function nowText(ep, t) {
    const tc = Math.min(t, ep.duration);
    const labels = ep.doc.labels[ep.focus || ep.ego.id] || {};
    const bits = [];
    for (const axis of ["lateral", "longitudinal", "interaction"]) {
      const r = labelAt(labels[axis], tc);
      if (r) bits.push(r[2] + (r[3] ? ` (${r[3]})` : ""));
    }
    let text = `now: ${bits.join(" | ") || "(no label)"}`;
    if (ep.measures) {
      const i = Math.round(tc * HZ) - ep.measures.s0;
      if (i >= 0 && i < ep.measures.n) {
        const v = (k) => ep.measures[k][i] === MISSING ? null : ep.measures[k][i] / 100;
        const ttc = v("ttc"), hw = v("headway");
        text += ` · speed ${fmt(v("speed"), 1, "m/s")} · headway ` +
          (hw === null ? "–" : hw >= 10 ? "≥ 10 s" : fmt(hw, 2, "s")) + " · TTC " +
          (ttc === null ? "–" : ttc >= 10 ? "≥ 10 s" : fmt(ttc, 2, "s"));
      }
    }
    return text;
  }

  function draw() {
    if (!state.a) return;
    for (const ep of [state.a, state.b]) {
      if (!ep) continue;
      drawScene(ep, state.t);
      const ended = state.t > ep.duration + 1e-6;
      ep.view.now.textContent = nowText(ep, state.t);
      ep.view.now.classList.toggle("ended", ended);
      for (const part of [ep.view.timeline, ep.view.chart]) {
        if (!part) continue;
        const x = xOf(Math.min(state.t, part.duration), part.duration);
        part.playhead.setAttribute("x1", x);
        part.playhead.setAttribute("x2", x);
      }
    }
    $("time").textContent = `t = ${state.t.toFixed(1)} s / ${maxDuration().toFixed(1)} s`;
    $("scrub").value = state.t.toFixed(1);
    $("play").textContent = state.playing ? "pause" : "play";
    state.frames++;
  }

  // -- playback -----------------------------------------------------------------------
  let last = null;
  function tick(now) {
    if (!state.playing) { last = null; return; }
    if (last !== null) {
      state.t += (now - last) / 1000 * state.speed;
      if (state.t >= maxDuration()) { state.t = maxDuration(); state.playing = false; }
    }
    last = now;
    draw();
    if (state.playing) requestAnimationFrame(tick);
    else updateHash();
  }

  function play(on) {
    if (!state.a) return;
    state.playing = on === undefined ? !state.playing : on;
    if (state.playing && state.t >= maxDuration() - 1e-6) state.t = 0;
    draw();
    if (state.playing) { last = null; requestAnimationFrame(tick); } else updateHash();
  }

  function step(k) {
    if (!state.a) return;
    state.playing = false;
    state.t = Math.max(0, Math.min(maxDuration(), Math.round(state.t * HZ + k) / HZ));
    draw();
    updateHash();
  }

  function seek(t) {
    state.t = Math.max(0, Math.min(maxDuration(), t));
    draw();
    updateHash();
  }

  // -- the URL hash -------------------------------------------------------------------
  function decodePart(text) {
    // decodeURIComponent throws on a malformed escape ("%zz", a lone "%"): such a part of
    // an edited or truncated URL is dropped instead of stopping the viewer
    try {
      return decodeURIComponent(text);
    } catch (err) {
      return null;
    }
  }

  function parseHash() {
    const out = {};
    for (const part of location.hash.replace(/^#/, "").split("&")) {
      if (!part) continue;
      const k = part.indexOf("=");
      const key = decodePart(k < 0 ? part : part.slice(0, k));
      const value = k < 0 ? "" : decodePart(part.slice(k + 1));
      if (key !== null && value !== null) out[key] = value;  // a malformed part is ignored
    }
    return out;
  }

  function updateHash() {
    const bits = [];
    for (const [k, v] of Object.entries(state.filters)) if (v) bits.push([`f_${k}`, v]);
    if (state.a) {
      bits.push(["ep", state.a.doc.id]);
      bits.push(["b", state.b ? state.b.entry.policy : "(none)"]);
      bits.push(["t", state.t.toFixed(1)]);
    }
    const hash = "#" + bits.map(([k, v]) => `${k}=${encodeURIComponent(v)}`).join("&");
    if (hash !== location.hash) history.replaceState(null, "", hash);
  }

  function applyHash() {
    const h = parseHash();
    for (const k of Object.keys(state.filters)) state.filters[k] = h[`f_${k}`] || "";
    $("filter-env").value = state.filters.env;
    $("filter-policy").value = state.filters.policy;
    $("filter-label").value = state.filters.label || state.filters.sdl;
    $("filter-crash").value = state.filters.crash;
    $("filter-novel").value = state.filters.novel;
    renderList();
    let id = h.ep;
    if (!id && (h.env || h.seed || h.a)) {
      const e = state.index.episodes.find((o) => (!h.env || o.env === h.env) &&
        (!h.seed || String(o.seed) === h.seed) && (!h.a || o.policy === h.a) && o.replay);
      id = e && e.id;
    }
    if (!id && state.filters.sdl) {  // a link to a label: its first episode
      const e = state.index.episodes.find((o) => matches(o) && o.replay);
      id = e && e.id;
    }
    if (id) return openEpisode(id, h.b || null, parseFloat(h.t || "0") || 0);
    const first = state.index.episodes.find((o) => matches(o) && o.replay);
    if (first) return openEpisode(first.id, null, 0);
    showMessage("no episode to replay");
    return Promise.resolve();
  }

  // -- start ---------------------------------------------------------------------------
  function index(doc) {
    state.index = doc;
    state.hasInteraction = doc.episodes.some((e) => e.interaction);
    const r = doc.run;
    $("title").textContent = `tap-bench replay: ${r.name}`;
    document.title = `tap-bench replay ${r.name}`;
    $("subtitle").textContent = `${r.source} · suite ${r.suite} · SDL level ${r.level}` +
      (r.reference ? ` · reference policy ${r.reference}` : "") +
      ` · ${doc.episodes.length} episodes`;
    const uniq = (k) => [...new Set(doc.episodes.map((e) => e[k]))].sort();
    fillSelect($("filter-env"), uniq("env"));
    fillSelect($("filter-policy"), uniq("policy"));
    const onFilter = () => {
      state.filters.env = $("filter-env").value;
      state.filters.policy = $("filter-policy").value;
      const text = $("filter-label").value;
      if (text !== state.filters.sdl) { state.filters.sdl = ""; state.filters.label = text; }
      state.filters.crash = $("filter-crash").value;
      state.filters.novel = $("filter-novel").value;
      renderList();
      updateHash();
    };
    for (const id of ["filter-env", "filter-policy", "filter-crash", "filter-novel"]) {
      $(id).addEventListener("change", onFilter);
    }
    $("filter-label").addEventListener("input", onFilter);
    $("filter-clear").addEventListener("click", () => {
      for (const k of Object.keys(state.filters)) state.filters[k] = "";
      for (const id of ["filter-env", "filter-policy", "filter-label", "filter-crash",
                        "filter-novel"]) $(id).value = "";
      renderList();
      updateHash();
    });
    $("play").addEventListener("click", () => play());
    $("step-back").addEventListener("click", () => step(-1));
    $("step-fwd").addEventListener("click", () => step(1));
    $("scrub").addEventListener("input", (ev) => { state.playing = false;
                                                   seek(parseFloat(ev.target.value)); });
    $("speed").addEventListener("change", (ev) => { state.speed = parseFloat(ev.target.value); });
    $("zoom").addEventListener("change", (ev) => { state.zoom = parseFloat(ev.target.value);
                                                   draw(); });
    $("b-policy").addEventListener("change", (ev) => {
      setB(ev.target.value);
      state.t = Math.min(state.t, maxDuration());
      build(); draw(); updateHash();
    });
    document.addEventListener("keydown", (ev) => {
      if (ev.target.tagName === "INPUT" || ev.target.tagName === "SELECT") return;
      if (ev.key === " ") { ev.preventDefault(); play(); }
      else if (ev.key === "ArrowRight") step(1);
      else if (ev.key === "ArrowLeft") step(-1);
    });
    window.addEventListener("hashchange", () => { state.ready = applyHash(); });
    state.ready = applyHash();
  }

  return {index, chunk, state, play, step, seek, openEpisode, labelAt, signalsAt};
})();
