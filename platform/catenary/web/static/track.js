/* The track view (templates/track.html): residual thickness, height and stagger along the
   chainage in three uPlot charts sharing their x axis, fed by GET /api/v1/tracks/profile.
   Every zoom or pan fetches the window again (debounced) with the plot's width in pixel
   columns, so the server reads the coarsest envelope level that fills the screen (raw
   samples below about 1 km). The window is kept in the address (history.replaceState). */
(function () {
  "use strict";

  const config = JSON.parse(document.getElementById("track-view").textContent);
  const LEVEL_COLOURS = { plan: "176,137,0", urgent: "217,96,15", critical: "192,35,26" };
  const WIRE_COLOURS = ["31,111,180", "122,62,157", "0,128,128", "120,90,40"];
  const RUN_ALPHA = { latest: 1.0, previous: 0.35 };
  const PANELS = [
    {
      title: "Residual thickness [mm]", min: "min_residual_thickness_mm",
      max: "max_residual_thickness_mm", height: 230, alerts: (a) => a !== "geometry",
    },
    {
      title: "Height above rail [mm]", min: "height_min_mm", max: "height_max_mm",
      height: 190, design: "design_height_mm", geometry: "height", alerts: (a) => a === "geometry",
    },
    {
      title: "Stagger [mm]", min: "stagger_min_mm", max: "stagger_max_mm", height: 190,
      design: "design_stagger_mm", geometry: "stagger", alerts: (a) => a === "geometry",
    },
  ];
  const DEBOUNCE_MS = 250;
  const MIN_WIDTH_M = 10;
  const RAW_GAP_M = 2.0; // raw samples further apart than this are not joined by a line

  const holder = document.getElementById("track-charts");
  const statusText = document.getElementById("track-status");
  const windowText = document.getElementById("track-window");
  const resolutionText = document.getElementById("track-resolution");

  let view = { from: config.from_m, to: config.to_m };
  let extent = null;
  let profile = null;
  let charts = [];
  let timer = null;
  let controller = null;

  /* A chainage as kilometres + metres (12+345.6; whole metres with digits = 0). */
  function chainage(m, digits = 1) {
    const sign = m < 0 ? "-" : "";
    const km = Math.floor(Math.abs(m) / 1000);
    const rest = (Math.abs(m) - km * 1000).toFixed(digits);
    return `${sign}${km}+${rest.padStart(digits ? 4 + digits : 3, "0")}`;
  }

  function setStatus(text, failed) {
    statusText.textContent = text;
    statusText.classList.toggle("error", Boolean(failed));
  }

  function clamp(from, to) {
    let width = Math.max(to - from, MIN_WIDTH_M);
    if (extent) {
      const full = extent[1] - extent[0];
      width = Math.min(width, full);
      from = Math.min(Math.max(from, extent[0]), extent[1] - width);
    }
    return [from, from + width];
  }

  function keepInAddress() {
    const params = new URLSearchParams({
      line: config.line, track: config.track,
      from_m: view.from.toFixed(1), to_m: view.to.toFixed(1),
    });
    history.replaceState(null, "", `${location.pathname}?${params}`);
    windowText.textContent = `${chainage(view.from)} to ${chainage(view.to)}`;
  }

  /* Show [from, to] at once with the data at hand, and fetch it again shortly. */
  function showWindow(from, to) {
    [view.from, view.to] = clamp(from, to);
    charts.forEach((u) => u.setScale("x", { min: view.from, max: view.to }));
    keepInAddress();
    clearTimeout(timer);
    timer = setTimeout(load, DEBOUNCE_MS);
  }

  function plotColumns() {
    const width = charts.length ? charts[0].bbox.width / devicePixelRatio : holder.clientWidth - 70;
    return Math.min(4000, Math.max(100, Math.round(width)));
  }

  async function load() {
    if (controller) controller.abort();
    const mine = (controller = new AbortController());
    const params = new URLSearchParams({
      line: config.line, track: config.track, columns: String(plotColumns()),
    });
    if (view.from != null) params.set("from_m", String(view.from));
    if (view.to != null) params.set("to_m", String(view.to));
    setStatus("Loading…");
    let answer, body;
    try {
      answer = await fetch(`${config.profile_url}?${params}`, {
        credentials: "same-origin", signal: mine.signal, headers: { Accept: "application/json" },
      });
      body = await answer.json().catch(() => ({ error: `answer ${answer.status}` }));
    } catch (error) {
      if (!mine.signal.aborted) setStatus(`Cannot reach the service: ${error.message}`, true);
      return;
    }
    if (mine.signal.aborted) return; // a newer window is on its way
    if (!answer.ok || body.error) {
      setStatus(body.error || `answer ${answer.status}`, true);
      return;
    }
    profile = body;
    extent = body.extent_m;
    view = { from: body.from_m, to: body.to_m };
    keepInAddress();
    resolutionText.textContent = body.level_m == null ? "raw samples"
      : `${body.resolution} envelope level, minimum and maximum per ${body.bin_m} m`;
    const problems = [body.latest, body.previous].filter((r) => r && r.problem).map((r) => r.problem);
    const runs = body.latest ? "" : "no run of this track yet";
    setStatus(problems.length ? problems.join("; ") : runs, problems.length > 0);
    draw();
  }

  /* One wire position's points, with a null between points too far apart to be joined. */
  function table(wire, panel, level) {
    const gap = level == null ? RAW_GAP_M : 1.5 * level;
    const shift = level == null ? 0 : level / 2;
    const low = wire[panel.min];
    const high = wire[panel.max];
    const xs = [], lows = [], highs = [];
    wire.chainage_m.forEach((x, i) => {
      if (i > 0 && x - wire.chainage_m[i - 1] > gap) {
        xs.push((x + wire.chainage_m[i - 1]) / 2 + shift);
        lows.push(null);
        highs.push(null);
      }
      xs.push(x + shift);
      lows.push(low[i]);
      highs.push(high ? high[i] : null);
    });
    return high ? [xs, lows, highs] : [xs, lows];
  }

  function limitsOf(panel) {
    const found = [];
    if (!panel.geometry) {
      profile.limits.wear.forEach((w) => found.push({
        value: w.residual_thickness_mm, level: w.level,
        label: `${w.wire_type} ${w.level}: ${w.criterion}`,
      }));
    } else {
      profile.limits.geometry.filter((g) => g.check === panel.geometry).forEach((g) => {
        const label = `${g.level}: ${g.criterion}`;
        [g.min_mm, g.max_mm].forEach((v) => v != null && found.push({ value: v, level: g.level, label }));
        if (g.max_abs_mm != null) {
          found.push({ value: g.max_abs_mm, level: g.level, label });
          found.push({ value: -g.max_abs_mm, level: g.level, label });
        }
      });
    }
    const seen = new Set();
    return found.filter((l) => !seen.has(`${l.value}|${l.level}`) && seen.add(`${l.value}|${l.level}`));
  }

  function yRange(panel, min, max) {
    const values = limitsOf(panel).map((l) => l.value);
    if (panel.design) profile.masts[panel.design].forEach((v) => v != null && values.push(v));
    if (min != null && isFinite(min)) values.push(min, max);
    if (!values.length) return [0, 1];
    const low = Math.min(...values), high = Math.max(...values);
    const pad = Math.max((high - low) * 0.06, 0.5);
    return [low - pad, high + pad];
  }

  function spanAt(x) {
    const masts = profile.masts;
    let found = -1;
    masts.chainage_m.forEach((c, i) => { if (c <= x) found = i; });
    if (found < 0 || found === masts.chainage_m.length - 1) return null;
    return masts.mast[found];
  }

  function openSpan(u, offsetX) {
    const mast = spanAt(u.posToVal(offsetX, "x"));
    if (mast == null) return;
    const params = new URLSearchParams({ line: config.line, track: config.track, mast });
    location.assign(`${config.span_url}?${params}`);
  }

  function shadeAlerts(u, panel) {
    const ctx = u.ctx, { top, height, left, width } = u.bbox;
    const alerts = profile.alerts;
    ctx.save();
    alerts.id.forEach((id, i) => {
      if (!panel.alerts(alerts.kind[i])) return;
      let x0 = u.valToPos(alerts.start_chainage_m[i], "x", true);
      let x1 = u.valToPos(alerts.end_chainage_m[i], "x", true);
      x0 = Math.max(x0, left);
      x1 = Math.min(Math.max(x1, x0 + 2 * devicePixelRatio), left + width);
      if (x1 <= left || x0 >= left + width) return;
      ctx.fillStyle = `rgba(${LEVEL_COLOURS[alerts.level[i]] || "0,0,0"},0.18)`;
      ctx.fillRect(x0, top, x1 - x0, height);
    });
    ctx.restore();
  }

  function overlay(u, panel, first) {
    const ctx = u.ctx, { top, height, left, width } = u.bbox;
    const dpr = devicePixelRatio;
    ctx.save();
    ctx.beginPath();
    ctx.rect(left, top, width, height);
    ctx.clip();
    ctx.font = `${11 * dpr}px system-ui, sans-serif`;
    ctx.lineWidth = dpr;
    ctx.setLineDash([6 * dpr, 4 * dpr]);
    limitsOf(panel).forEach((l) => {
      const y = Math.round(u.valToPos(l.value, "y", true)) + 0.5;
      ctx.strokeStyle = ctx.fillStyle = `rgb(${LEVEL_COLOURS[l.level] || "0,0,0"})`;
      ctx.beginPath();
      ctx.moveTo(left, y);
      ctx.lineTo(left + width, y);
      ctx.stroke();
      ctx.textAlign = "right";
      ctx.fillText(l.label, left + width - 4 * dpr, y - 3 * dpr);
    });
    ctx.setLineDash([]);
    const masts = profile.masts;
    ctx.strokeStyle = "rgba(29,36,48,0.55)";
    ctx.fillStyle = "rgb(29,36,48)";
    ctx.textAlign = "left";
    let labelEnd = -Infinity;
    masts.chainage_m.forEach((c, i) => {
      const x = Math.round(u.valToPos(c, "x", true)) + 0.5;
      if (x < left || x > left + width) return;
      ctx.beginPath();
      ctx.moveTo(x, top + height - 8 * dpr);
      ctx.lineTo(x, top + height);
      ctx.stroke();
      if (first && x > labelEnd + 6 * dpr) {
        ctx.fillText(masts.mast[i], x + 2 * dpr, top + 12 * dpr);
        labelEnd = x + 2 * dpr + ctx.measureText(masts.mast[i]).width;
      }
    });
    if (panel.design) {
      ctx.fillStyle = "rgb(42,125,58)";
      const r = 4 * dpr;
      masts[panel.design].forEach((v, i) => {
        if (v == null) return;
        const x = u.valToPos(masts.chainage_m[i], "x", true);
        const y = u.valToPos(v, "y", true);
        ctx.beginPath();
        ctx.moveTo(x, y - r);
        ctx.lineTo(x + r, y);
        ctx.lineTo(x, y + r);
        ctx.lineTo(x - r, y);
        ctx.closePath();
        ctx.fill();
      });
    }
    ctx.restore();
  }

  function pan(u, event) {
    const startX = event.clientX, start = { ...view };
    const metresPerPixel = (start.to - start.from) / (u.bbox.width / devicePixelRatio);
    u.root.classList.add("panning");
    const move = (e) => {
      const shift = -(e.clientX - startX) * metresPerPixel;
      showWindow(start.from + shift, start.to + shift);
    };
    const up = () => {
      u.root.classList.remove("panning");
      document.removeEventListener("mousemove", move);
      document.removeEventListener("mouseup", up);
    };
    document.addEventListener("mousemove", move);
    document.addEventListener("mouseup", up);
  }

  /* A series' gaps: wherever a null stands between two of its points (``table`` puts one in
     each stretch where nothing was measured), whatever uPlot's own null handling does when
     several points share a pixel column. */
  function nullGaps(u, seriesIdx, idx0, idx1) {
    const xs = u.data[0];
    const ys = u.data[seriesIdx];
    const gaps = [];
    let last = null;
    let broken = false;
    for (let i = idx0; i <= idx1; i++) {
      const y = ys[i];
      if (y === null) broken = last !== null;
      else if (y !== undefined) {
        if (broken) uPlot.addGap(gaps, Math.round(u.valToPos(xs[last], "x", true)), Math.round(u.valToPos(xs[i], "x", true)));
        last = i;
        broken = false;
      }
    }
    return gaps;
  }

  function chartOf(panel, index, width) {
    const level = profile.bin_m;
    const tables = [];
    const series = [{ label: "chainage [m]" }];
    const bands = [];
    // the previous run first: the latest is drawn over it
    [["previous", profile.previous], ["latest", profile.latest]].forEach(([name, run]) => {
      if (!run) return;
      run.wires.forEach((wire) => {
        const rgb = WIRE_COLOURS[wire.wire_position % WIRE_COLOURS.length];
        const alpha = RUN_ALPHA[name];
        const stroke = `rgba(${rgb},${alpha})`;
        const t = table(wire, panel, level);
        tables.push(t);
        const label = `run ${run.id} wire ${wire.wire_position}`;
        if (t.length === 3) {
          series.push({ label: `${label} min`, stroke, width: 1, points: { show: false }, gaps: nullGaps });
          series.push({ label: `${label} max`, stroke, width: 1, points: { show: false }, gaps: nullGaps });
          bands.push({ series: [series.length - 1, series.length - 2], fill: `rgba(${rgb},${alpha * 0.3})` });
        } else {
          series.push({ label, stroke, width: 1, points: { show: false }, gaps: nullGaps });
        }
      });
    });
    const data = tables.length ? uPlot.join(tables) : [[view.from, view.to]];
    const last = index === PANELS.length - 1;
    let down = null;
    const options = {
      width, height: panel.height,
      series, bands,
      legend: { show: false },
      scales: {
        x: { time: false, range: () => [view.from, view.to] },
        y: { range: (u, min, max) => yRange(panel, min, max) },
      },
      axes: [
        {
          space: 90,
          size: last ? 40 : 12,
          values: (u, splits) => splits.map((v) => (last ? chainage(v, view.to - view.from > 2000 ? 0 : 1) : "")),
        },
        { size: 64 },
      ],
      cursor: {
        sync: { key: "track" },
        drag: { x: true, y: false, setScale: false },
        bind: {
          mousedown: (u, target, handler) => (e) => {
            down = { x: e.clientX, shift: e.shiftKey };
            if (e.shiftKey) {
              pan(u, e);
              return null;
            }
            return handler(e);
          },
          mouseup: (u, target, handler) => (e) => {
            if (down && !down.shift && Math.abs(e.clientX - down.x) < 3) {
              openSpan(u, e.clientX - u.over.getBoundingClientRect().left);
            }
            down = null;
            return handler(e);
          },
        },
      },
      hooks: {
        drawClear: [(u) => shadeAlerts(u, panel)],
        draw: [(u) => overlay(u, panel, index === 0)],
        setSelect: [(u) => {
          const { left, width: w } = u.select;
          if (w < 3) return;
          u.setSelect({ left: 0, width: 0, top: 0, height: 0 }, false);
          showWindow(u.posToVal(left, "x"), u.posToVal(left + w, "x"));
        }],
        setCursor: [(u) => {
          const x = u.cursor.left;
          if (x == null || x < 0) return;
          windowText.title = `cursor at ${chainage(u.posToVal(x, "x"))}`;
        }],
      },
    };
    const box = document.createElement("section");
    box.className = "track-chart";
    const heading = document.createElement("h2");
    heading.textContent = panel.title;
    box.append(heading);
    holder.append(box);
    const u = new uPlot(options, data, box);
    u.over.addEventListener("wheel", (e) => {
      e.preventDefault();
      const x = u.posToVal(e.clientX - u.over.getBoundingClientRect().left, "x");
      const factor = e.deltaY < 0 ? 0.8 : 1.25;
      showWindow(x - (x - view.from) * factor, x + (view.to - x) * factor);
    }, { passive: false });
    return u;
  }

  function draw() {
    charts.forEach((u) => u.destroy());
    holder.replaceChildren();
    const width = Math.max(300, holder.clientWidth);
    charts = PANELS.map((panel, i) => chartOf(panel, i, width));
  }

  document.querySelectorAll(".track-toolbar [data-action]").forEach((button) => {
    button.addEventListener("click", () => {
      if (view.from == null) return;
      const width = view.to - view.from, middle = (view.from + view.to) / 2;
      const action = button.dataset.action;
      if (action === "pan-left") showWindow(view.from - width / 2, view.to - width / 2);
      else if (action === "pan-right") showWindow(view.from + width / 2, view.to + width / 2);
      else if (action === "zoom-in") showWindow(middle - width / 4, middle + width / 4);
      else if (action === "zoom-out") showWindow(middle - width, middle + width);
      else if (action === "full" && extent) showWindow(extent[0], extent[1]);
    });
  });

  let resizing = null;
  window.addEventListener("resize", () => {
    clearTimeout(resizing);
    resizing = setTimeout(() => profile && (draw(), load()), DEBOUNCE_MS);
  });

  load();
})();
