// The cockpit's page script: the live view (server-sent events, an SVG plot drawn here) and the operator's
// confirmed actions; a running session's own page follows the same stream (its progress, plot, DUTs,
// summary and events move; when the run ends it is shown again, finished). Plain JavaScript, nothing
// loaded from elsewhere; every text from the server goes into the page through textContent, never as HTML.
"use strict";

(function () {
  const body = document.body;
  const csrfMeta = document.querySelector('meta[name="csrf-token"]');
  // What tests and the bench read: when each point was first seen here (ms since the epoch).
  window.cockpit = { messages: 0, firstMessageAt: null, pointSeen: {}, state: null };
  if (body.dataset.page === "live" || (body.dataset.page === "session" && body.dataset.events)) {
    live();
  }

  function live() {
    const $ = (id) => document.getElementById(id);
    const st = { summary: null, telemetry: [], events: [] };
    window.cockpit.state = st;
    // Drawing is what costs the machine: the text at most every TEXT_MS, the plot at most every PLOT_MS.
    const TEXT_MS = 1000, PLOT_MS = 2000;
    const pending = { events: [] }; // events received, not drawn yet
    let textTimer = null, plotTimer = null, lastPlot = 0;
    let awaiting = null; // the action asked for, until the run records it
    const onSessionPage = body.dataset.page === "session";
    let lastEventShown = Number(body.dataset.lastEvent || 0); // the session page lists these already
    let sawRunning = onSessionPage; // it was drawn running: any other state means the run has ended

    const source = new EventSource(body.dataset.events);
    source.addEventListener("state", (ev) => onMessage(JSON.parse(ev.data)));
    source.addEventListener("open", () => setNote(""));
    source.addEventListener("error", () => setNote("connection to the server lost; reconnecting..."));
    window.addEventListener("resize", () => schedulePlot());
    if ($("ask-pause")) setUpActions();

    function onMessage(msg) {
      const now = Date.now();
      const cp = window.cockpit;
      cp.messages += 1;
      if (cp.firstMessageAt === null) cp.firstMessageAt = now;
      for (const id of msg.new_points) {
        if (!(id in cp.pointSeen)) cp.pointSeen[id] = now;
      }
      if (msg.reset) {
        st.telemetry = [];
        st.events = [];
        pending.events = [];
        if ($("events")) $("events").replaceChildren();
      }
      st.summary = msg.summary;
      st.telemetry.push(...msg.telemetry);
      st.events.push(...msg.events);
      if (st.events.length > 1000) st.events.splice(0, st.events.length - 1000);
      pending.events.push(...msg.events);
      if (msg.error) setNote("the session could not be read just now (" + msg.error + "); trying again");
      scheduleText();
      if (msg.telemetry.length || msg.reset) schedulePlot();
    }

    function scheduleText() {
      if (textTimer !== null) return;
      textTimer = setTimeout(() => {
        textTimer = null;
        renderSummary(st.summary);
        renderEvents(pending.events.splice(0));
      }, window.cockpit.messages === 1 ? 0 : TEXT_MS); // the first state at once
    }

    // --- summary ----------------------------------------------------------------------------------
    function renderSummary(s) {
      if (!s || !s.run) return;
      put("meta", "plan " + s.plan + " on station " + s.station +
        (s.simulated ? " (simulated: times are the simulation's)" : ""));
      const badge = $("run-state");
      if (badge) {
        setText(badge, s.run.state);
        badge.className = "badge state-" + s.run.state.replace(/[^a-z]+/g, "-");
      }
      put("s-state", s.run.state);
      put("s-reason", s.run.exit_reason || "-");
      const p = s.progress;
      $("progress").max = Math.max(p.planned, 1);
      $("progress").value = p.done;
      const points = p.done + " of " + p.planned + " points" + (p.failed ? " (" + p.failed + " failed)" : "");
      setText($("progress-text"), points);
      put("s-points", points);
      const eta = [];
      if (p.eta_run_s !== null) eta.push("about " + duration(p.eta_run_s) + " left on the run's clock");
      if (p.eta_wall_s !== null) eta.push(duration(p.eta_wall_s) + " at the pace seen here");
      if (p.postrun) eta.push(p.postrun);
      setText($("eta"), eta.join("; "));
      if (p.current) {
        setText($("current"), "point " + p.current.id + " at " + num(p.current.setpoint_c, 1) + " \u00b0C");
        setText($("target"), target(p.current.target));
      } else {
        setText($("current"), s.run.state === "running" ? "-" : "no point being taken");
        setText($("target"), "");
      }
      const running = s.run.state === "running";
      sawRunning = sawRunning || running;
      if ($("actions")) $("actions").hidden = !running;
      if (!running && onSessionPage && sawRunning) {
        setNote("the run has ended; showing the finished session...");
        source.close();
        location.reload(); // its calibrations, acceptance and downloads, as for any finished session
        return;
      }
      if (!running) {
        const why = s.run.exit_reason ? s.run.state + ": " + s.run.exit_reason : s.run.state;
        const resume = s.run.completed ? "" : " Continue it with: rig run --resume " + body.dataset.session;
        setNote(why + "." + resume);
      }
      renderDuts(s.duts);
    }

    let dutsShown = "";
    function renderDuts(duts) {
      const shown = JSON.stringify(duts);
      if (shown === dutsShown) return; // unchanged: no work for the page
      dutsShown = shown;
      const rows = duts.map((d) => {
        const tr = document.createElement("tr");
        const verdict = String(d.verdict);
        for (const text of [d.name, num(d.temp_c, 2), String(d.n), num(d.rms_nt, 1), verdict]) {
          const td = document.createElement("td");
          td.textContent = text;
          tr.appendChild(td);
        }
        const cls = verdict.startsWith("PASS") ? "pass" : verdict.startsWith("FAIL") || verdict.startsWith("likely FAIL") ? "fail" : "";
        if (cls) tr.lastChild.className = cls;
        return tr;
      });
      $("duts").tBodies[0].replaceChildren(...rows);
    }

    function renderEvents(events) {
      if (onSessionPage) {
        tableEvents(events);
        return;
      }
      const list = $("events");
      for (const e of events) {
        const li = document.createElement("li");
        li.className = "kind-" + e.kind.replace(/[^a-z_]+/g, "") + " level-" + e.level.toLowerCase();
        const when = document.createElement("span");
        when.className = "t";
        when.textContent = clock(e.t);
        const kind = document.createElement("span");
        kind.className = "kind";
        kind.textContent = e.kind;
        const text = document.createElement("span");
        text.className = "msg";
        text.textContent = e.message;
        const where = document.createElement("span");
        where.className = "muted";
        where.textContent = [e.point, e.device, e.code].filter(Boolean).join(" \u00b7 ");
        li.append(when, " ", kind, " ", text, " ", where);
        list.prepend(li);
        if (awaiting && e.kind === "request") setStatus("the run took the request: " + e.message);
        if (awaiting && (e.kind === "pause" || e.kind === "exit")) {
          setStatus(e.message);
          awaiting = null;
        }
      }
      while (list.children.length > 300) list.lastChild.remove();
    }

    // The session page's table: newest first, the columns the server wrote, each new event once.
    function tableEvents(events) {
      const rows = $("event-table").tBodies[0];
      for (const e of events) {
        if (e.id <= lastEventShown) continue;
        lastEventShown = e.id;
        const tr = document.createElement("tr");
        for (const t of [utc(e.t), e.kind, e.code, e.point || "", e.device || "", e.message]) {
          const td = document.createElement("td");
          td.textContent = t;
          tr.appendChild(td);
        }
        rows.prepend(tr);
      }
      while (rows.children.length > 500) rows.lastChild.remove();
    }

    // --- the plot ---------------------------------------------------------------------------------
    function schedulePlot() {
      if (plotTimer !== null) return;
      plotTimer = setTimeout(() => requestAnimationFrame(() => {
        plotTimer = null;
        lastPlot = Date.now();
        draw();
      }), Math.max(0, PLOT_MS - (Date.now() - lastPlot)));
    }

    function series() {
      const rows = st.telemetry;
      if (!rows.length) return [];
      const t0 = rows[0][0];
      const x = (r) => (r[0] - t0) / 3600;
      const out = [
        { name: "set point", color: "#555555", dash: "6 4", pts: rows.map((r) => [x(r), r[2] !== null ? r[2] : r[1]]) },
        { name: "chamber air", color: "#d62728", pts: rows.map((r) => [x(r), r[3]]) },
      ];
      const palette = ["#1f77b4", "#2ca02c", "#9467bd", "#ff7f0e", "#17becf", "#8c564b", "#e377c2", "#7f7f7f", "#bcbd22"];
      const names = [];
      for (const r of rows) for (const k of Object.keys(r[4])) if (!names.includes(k)) names.push(k);
      names.sort().forEach((name, i) => {
        out.push({ name: name, color: palette[i % palette.length], pts: rows.map((r) => [x(r), r[4][name] ?? null]) });
      });
      return out;
    }

    function draw() {
      const box = $("chart");
      const all = series();
      const legend = $("legend");
      if (!all.length) {
        box.replaceChildren(text("no temperatures recorded yet", "muted"));
        legend.replaceChildren();
        return;
      }
      const w = Math.max(280, box.clientWidth || 600);
      const h = Math.round(Math.min(360, Math.max(200, w * 0.45)));
      const m = { l: 46, r: 12, t: 10, b: 34 };
      const xs = [], ys = [];
      for (const s of all) for (const [x, y] of s.pts) if (y !== null) { xs.push(x); ys.push(y); }
      const xMax = Math.max(...xs, 1e-3);
      let yMin = Math.min(...ys), yMax = Math.max(...ys);
      if (yMax - yMin < 2) { yMin -= 1; yMax += 1; }
      const pad = (yMax - yMin) * 0.05;
      yMin -= pad; yMax += pad;
      const px = (x) => m.l + (x / xMax) * (w - m.l - m.r);
      const py = (y) => m.t + (1 - (y - yMin) / (yMax - yMin)) * (h - m.t - m.b);
      const svg = el("svg", { width: w, height: h, viewBox: "0 0 " + w + " " + h, role: "img",
        "aria-label": "temperatures against time" });
      for (const v of ticks(yMin, yMax, 5)) {
        svg.append(el("line", { class: "grid", x1: m.l, x2: w - m.r, y1: py(v), y2: py(v) }));
        svg.append(svgText(m.l - 6, py(v) + 4, String(v), "end"));
      }
      for (const v of ticks(0, xMax, Math.max(2, Math.floor(w / 110)))) {
        svg.append(el("line", { class: "grid", x1: px(v), x2: px(v), y1: m.t, y2: h - m.b }));
        svg.append(svgText(px(v), h - m.b + 16, String(v), "middle"));
      }
      svg.append(svgText(w - m.r, h - 4, st.summary && st.summary.simulated ? "h (simulated)" : "h", "end"));
      svg.append(svgText(4, m.t + 10, "\u00b0C", "start"));
      for (const s of all) {
        let d = "";
        let pen = "M";
        for (const [x, y] of s.pts) {
          if (y === null) { pen = "M"; continue; }
          d += pen + px(x).toFixed(1) + " " + py(y).toFixed(1) + " ";
          pen = "L";
        }
        const path = el("path", { d: d, fill: "none", stroke: s.color, "stroke-width": 1.6 });
        if (s.dash) path.setAttribute("stroke-dasharray", s.dash);
        svg.append(path);
      }
      box.replaceChildren(svg);
      legend.replaceChildren(...all.map((s) => {
        const item = document.createElement("span");
        item.className = "key";
        const sw = el("svg", { width: 14, height: 10, "aria-hidden": "true" });
        sw.append(el("line", { x1: 0, x2: 14, y1: 5, y2: 5, stroke: s.color, "stroke-width": 3 }));
        item.append(sw, " " + s.name);
        return item;
      }));
    }

    // --- operator actions -------------------------------------------------------------------------
    function setUpActions() {
      const questions = {
        pause: "Pause the campaign at its next safe point? The engine finishes or drops the point in hand " +
          "(nothing half-recorded), makes every device safe and, with nobody at its terminal, ends the run " +
          "there: continue it with rig run --resume.",
        abort: "Abort the campaign? The engine stops at its next safe point and leaves every device in its " +
          "safe state. The points taken so far stay recorded.",
      };
      let asked = null;
      for (const action of ["pause", "abort"]) {
        $("ask-" + action).addEventListener("click", () => {
          asked = action;
          $("confirm-text").textContent = questions[action];
          $("confirm-yes").textContent = "Yes, " + action;
          $("confirm-yes").className = action === "abort" ? "danger" : "";
          $("confirm").hidden = false;
        });
      }
      $("confirm-no").addEventListener("click", () => {
        asked = null;
        $("confirm").hidden = true;
      });
      $("confirm-yes").addEventListener("click", () => {
        if (!asked) return;
        const action = asked;
        asked = null;
        $("confirm").hidden = true;
        send(action);
      });
    }

    function send(action) {
      const form = new URLSearchParams({ action: action, confirm: "yes", csrf: csrfMeta.content });
      setStatus("sending the " + action + " request...");
      fetch(body.dataset.action, { method: "POST", body: form, credentials: "same-origin" })
        .then((r) => r.text().then((t) => [r, t]))
        .then(([r, t]) => {
          if (r.ok) {
            awaiting = action;
            setStatus(JSON.parse(t).message + "; waiting for the run to record it");
          } else {
            const doc = new DOMParser().parseFromString(t, "text/html");
            const why = doc.querySelector(".bad");
            setStatus("refused (HTTP " + r.status + "): " + (why ? why.textContent : r.statusText));
          }
        })
        .catch(() => setStatus("the server could not be reached; nothing was requested"));
    }

    // --- small helpers ----------------------------------------------------------------------------
    function setStatus(t) { put("action-status", t); }
    function setNote(t) { put("stream-note", t); }
    function put(id, t) { const node = $(id); if (node) setText(node, t); }
  }

  // Writes text only when it changed: an unchanged page costs the browser nothing.
  function setText(node, t) {
    if (node.textContent !== t) node.textContent = t;
  }

  function el(name, attrs) {
    const node = document.createElementNS("http://www.w3.org/2000/svg", name);
    for (const [k, v] of Object.entries(attrs || {})) node.setAttribute(k, String(v));
    return node;
  }

  function svgText(x, y, t, anchor) {
    const node = el("text", { x: x, y: y, "text-anchor": anchor, class: "tick" });
    node.textContent = t;
    return node;
  }

  function text(t, cls) {
    const p = document.createElement("p");
    p.className = cls;
    p.textContent = t;
    return p;
  }

  function ticks(lo, hi, n) {
    const span = hi - lo;
    if (!(span > 0)) return [lo];
    const raw = span / n;
    const mag = Math.pow(10, Math.floor(Math.log10(raw)));
    const step = [1, 2, 5, 10].map((f) => f * mag).find((s) => span / s <= n) || 10 * mag;
    const out = [];
    for (let v = Math.ceil(lo / step) * step; v <= hi + step * 1e-9; v += step) out.push(+v.toFixed(10));
    return out;
  }

  function num(x, digits) {
    return x === null || x === undefined ? "-" : Number(x).toFixed(digits);
  }

  // A point's target as the session records it (the field source's record: {"field_nt": [x, y, z]},
  // {"az_deg": a, "el_deg": e}): each key's last part is its unit.
  function target(t) {
    if (!t || typeof t !== "object") return "";
    const units = { nt: "nT", deg: "\u00b0", a: "A", c: "\u00b0C" };
    const parts = Object.entries(t).map(([key, value]) => {
      const m = /^(.*)_([a-z]+)$/.exec(key);
      const name = m && m[2] in units ? m[1] : key;
      const unit = m && m[2] in units ? units[m[2]] : "";
      const shown = Array.isArray(value) ? "(" + value.map((v) => +Number(v).toPrecision(6)).join(", ") + ")"
        : String(+Number(value).toPrecision(6));
      return name.replace(/_/g, " ") + " " + shown + (unit === "\u00b0" ? unit : " " + unit);
    });
    return "target: " + parts.join(", ");
  }

  function duration(s) {
    s = Math.max(0, Math.round(s));
    const h = Math.floor(s / 3600), m = Math.floor((s % 3600) / 60);
    if (h) return h + " h " + m + " min";
    if (m) return m + " min " + (s % 60) + " s";
    return s + " s";
  }

  function utc(t) { // as the server writes it: 2026-01-01 00:12:30 UTC
    return new Date(t * 1000).toISOString().slice(0, 19).replace("T", " ") + " UTC";
  }

  function clock(t) {
    const d = new Date(t * 1000);
    return d.toISOString().slice(11, 19);
  }
})();
