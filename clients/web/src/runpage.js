// A job's run page: its inputs and parameters, its progress, its output files, and its
// results as its kind declares them (GET /jobs/{id}/view: figures, plots, pictures —
// contract/views.py). Nothing here knows a service: a new kind's panels draw the same way.
import { api, followJob } from "./api.js";
import { el, sizeText, statusNode } from "./dom.js";
import { JobPlayer } from "./player.js";

const SVG = "http://www.w3.org/2000/svg";
const COLOURS = ["#1f77b4", "#d62728", "#2ca02c", "#ff7f0e", "#9467bd", "#8c564b"];
const PLOT = { width: 640, height: 360, left: 76, right: 16, top: 16, bottom: 44 };

function svg(tag, attributes = {}, ...children) {
  const node = document.createElementNS(SVG, tag);
  for (const [key, value] of Object.entries(attributes)) node.setAttribute(key, String(value));
  node.append(...children);
  return node;
}

function valueText(figure) {
  if (figure.value === null || figure.value === undefined) return `unmeasured${figure.note ? ` (${figure.note})` : ""}`;
  const value = typeof figure.value === "number" && !Number.isInteger(figure.value)
    ? String(Number(figure.value.toPrecision(6))) : String(figure.value);
  return figure.unit ? `${value} ${figure.unit}` : value;
}

// ---- axes -----------------------------------------------------------------------------

// About five round steps between lo and hi.
function ticks(lo, hi) {
  const span = hi - lo || Math.abs(hi) || 1;
  const raw = span / 5;
  const power = 10 ** Math.floor(Math.log10(raw));
  const step = [1, 2, 5, 10].map((m) => m * power).find((s) => s >= raw);
  const out = [];
  for (let v = Math.ceil(lo / step) * step; v <= hi + step * 1e-9; v += step) out.push(Number(v.toPrecision(12)));
  return out;
}

function extent(values) {
  let lo = Infinity;
  let hi = -Infinity;
  for (const v of values) {
    if (Number.isFinite(v)) { lo = Math.min(lo, v); hi = Math.max(hi, v); }
  }
  if (!Number.isFinite(lo)) return [0, 1];
  if (lo === hi) return [lo - 0.5, hi + 0.5];
  return [lo, hi];
}

// The plot's data ranges: with equal axes one metre is as long across as up (a straight
// path stays a straight line, not a diagonal stretched to fill the box).
function ranges(plot) {
  const xs = [];
  const ys = [];
  for (const line of plot.lines) {
    line.x.forEach((x, k) => {
      const band = line.band ? line.band[k] : 0;
      xs.push(x - (plot.equal_axes ? band : 0), x + (plot.equal_axes ? band : 0));
      ys.push(line.y[k] - band, line.y[k] + band);
    });
  }
  let [x0, x1] = extent(xs);
  let [y0, y1] = extent(plot.log_y ? ys.filter((v) => v > 0).map(Math.log10) : ys);
  const pad = (lo, hi) => [lo - 0.04 * (hi - lo), hi + 0.04 * (hi - lo)];
  [x0, x1] = pad(x0, x1);
  [y0, y1] = pad(y0, y1);
  if (plot.equal_axes) {
    const w = PLOT.width - PLOT.left - PLOT.right;
    const h = PLOT.height - PLOT.top - PLOT.bottom;
    const perPixel = Math.max((x1 - x0) / w, (y1 - y0) / h);
    const cx = (x0 + x1) / 2;
    const cy = (y0 + y1) / 2;
    [x0, x1] = [cx - (perPixel * w) / 2, cx + (perPixel * w) / 2];
    [y0, y1] = [cy - (perPixel * h) / 2, cy + (perPixel * h) / 2];
  }
  return { x0, x1, y0, y1 };
}

function plotPanel(plot) {
  const r = ranges(plot);
  const w = PLOT.width - PLOT.left - PLOT.right;
  const h = PLOT.height - PLOT.top - PLOT.bottom;
  const X = (x) => PLOT.left + ((x - r.x0) / (r.x1 - r.x0)) * w;
  const yOf = (y) => (plot.log_y ? Math.log10(Math.max(y, 1e-300)) : y);
  const Y = (y) => PLOT.top + h - ((yOf(y) - r.y0) / (r.y1 - r.y0)) * h;
  const root = svg("svg", {
    viewBox: `0 0 ${PLOT.width} ${PLOT.height}`, class: "plot", role: "img", "aria-label": plot.title,
    "data-units-per-px": `${(r.x1 - r.x0) / w} ${(r.y1 - r.y0) / h}`,
  });
  const grid = svg("g", { class: "axes" });
  for (const t of ticks(r.x0, r.x1)) {
    grid.append(svg("line", { x1: X(t), x2: X(t), y1: PLOT.top, y2: PLOT.top + h }),
      svg("text", { x: X(t), y: PLOT.top + h + 16, "text-anchor": "middle" }, String(t)));
  }
  for (const t of ticks(r.y0, r.y1)) {
    const y = PLOT.top + h - ((t - r.y0) / (r.y1 - r.y0)) * h;
    grid.append(svg("line", { x1: PLOT.left, x2: PLOT.left + w, y1: y, y2: y }),
      svg("text", { x: PLOT.left - 6, y: y + 4, "text-anchor": "end" }, plot.log_y ? `1e${t}` : String(t)));
  }
  grid.append(
    svg("text", { x: PLOT.left + w / 2, y: PLOT.height - 6, "text-anchor": "middle", class: "axis-label" }, plot.x_label),
    svg("text", { x: 12, y: PLOT.top + h / 2, "text-anchor": "middle", class: "axis-label", transform: `rotate(-90 12 ${PLOT.top + h / 2})` }, plot.y_label),
  );
  root.append(grid);
  const legend = el("ul", { class: "plot-legend" });
  plot.lines.forEach((line, k) => {
    const colour = line.colour || COLOURS[k % COLOURS.length];
    const g = svg("g", { class: "series", "data-name": line.name });
    if (line.band && plot.equal_axes) {
      // the position's 1σ: a circle at each pose, together a band around the path
      const scale = w / (r.x1 - r.x0);
      const step = Math.max(1, Math.floor(line.x.length / 400));
      for (let i = 0; i < line.x.length; i += step) {
        g.append(svg("circle", { cx: X(line.x[i]), cy: Y(line.y[i]), r: Math.max(0.5, line.band[i] * scale), fill: colour, "fill-opacity": 0.08, stroke: "none", class: "band" }));
      }
    } else if (line.band) {
      const upper = line.x.map((x, i) => `${X(x)},${Y(line.y[i] + line.band[i])}`);
      const lower = line.x.map((x, i) => `${X(x)},${Y(line.y[i] - line.band[i])}`).reverse();
      g.append(svg("polygon", { points: [...upper, ...lower].join(" "), fill: colour, "fill-opacity": 0.15, class: "band" }));
    }
    if (line.style === "points") {
      for (let i = 0; i < line.x.length; i += 1) {
        g.append(svg("circle", { cx: X(line.x[i]), cy: Y(line.y[i]), r: 4, fill: "none", stroke: colour, "stroke-width": 2, class: "mark" }));
      }
    } else {
      const points = line.x.map((x, i) => `${X(x).toFixed(1)},${Y(line.y[i]).toFixed(1)}`).join(" ");
      g.append(svg("polyline", { points, fill: "none", stroke: colour, "stroke-width": 1.5 }));
    }
    root.append(g);
    legend.append(el("li", {}, el("span", { class: "swatch", style: `background:${colour}` }), `${line.name}${line.style === "points" ? ` (${line.x.length})` : ""}`));
  });
  return [root, legend];
}

// ---- pictures: layers of one image, a slider between them ---------------------------------

function picturePanel(panel, inspectionId, urls) {
  return panel.pictures.map((picture) => {
    const layers = picture.layers.map((name, k) => ({ name: picture.layer_names[k], id: picture.artifact_ids[k], scale: picture.layer_scales?.[k] || null }))
      .filter((layer) => layer.id > 0);
    const images = layers.map((layer) => el("img", { alt: `${picture.label}: ${layer.name}`, "data-layer": layer.name }));
    layers.forEach((layer, k) => {
      api.artifactContent(inspectionId, layer.id).then((blob) => {
        const url = URL.createObjectURL(blob);
        urls.push(url);
        images[k].src = url;
      }).catch((error) => { images[k].alt = `${layer.name}: ${error.message}`; });
    });
    const stack = el("div", { class: "layers" }, ...images);
    const caption = el("span", { class: "muted" });
    // the colour bar of the layer most in view (one whose colours mean a quantity)
    const bar = el("span", { class: "colour-bar", hidden: "" });
    const slider = el("input", { type: "range", min: "0", max: String(Math.max(0, layers.length - 1) * 100), value: "0", "aria-label": `${picture.label}: blend the layers` });
    const blend = () => {
      const at = Number(slider.value) / 100;
      images.forEach((image, k) => { image.style.opacity = String(Math.max(0, Math.min(1, 1 - Math.abs(at - k)))); });
      caption.textContent = layers.map((layer) => layer.name).join(" ↔ ");
      const scale = layers[Math.max(0, Math.min(layers.length - 1, Math.round(at)))]?.scale;
      bar.hidden = !scale;
      if (scale) {
        bar.replaceChildren(
          el("span", { class: "colour-bar-low" }, scale.low),
          el("span", { class: "colour-bar-ramp", style: `background: linear-gradient(90deg, ${scale.colours.join(", ")})` }),
          el("span", { class: "colour-bar-high" }, scale.high),
        );
      }
    };
    slider.addEventListener("input", blend);
    blend();
    return el("figure", { class: "picture" }, stack, layers.length > 1 ? slider : null, el("figcaption", {}, picture.label, " ", caption, " ", bar));
  });
}

function figuresPanel(panel) {
  return el("table", { class: "grid figures" }, el("tbody", {}, ...panel.figures.map((f) => el(
    "tr", {}, el("th", {}, f.label), el("td", { class: f.value === null ? "muted" : "" }, valueText(f)),
  ))));
}

function tablePanel(panel) {
  return [
    el("div", { class: "table-scroll" }, el("table", { class: "grid rows-table" },
      el("thead", {}, el("tr", {}, ...panel.columns.map((c) => el("th", {}, c)))),
      el("tbody", {}, ...panel.rows.map((row) => el("tr", {}, ...row.map((cell) => el("td", {}, cell === null ? "–" : String(cell)))))))),
    panel.note ? el("p", { class: "muted" }, panel.note) : null,
  ];
}

// The median of the heights whose `u` passes `keep` (null when none does).
function medianOf(u, h, keep) {
  const picked = h.filter((_, i) => keep(u[i])).sort((a, b) => a - b);
  return picked.length ? picked[Math.floor(picked.length / 2)] : null;
}

// One section across a seam: its points, the edges where the gap says they are, each
// panel's top level, and the values measured there with their σ.
function sectionPlot(seam, section) {
  const { u_mm: u, h_mm: h, gap_mm: gap } = section;
  const lines = [{ name: "points", x: u, y: h, style: "points", colour: "#6b7c93" }];
  const low = Math.min(...h, 0) - 1; // the edges drawn a millimetre past the points
  const high = Math.max(...h, 0) + 1;
  if (gap !== null && gap !== undefined) {
    const half = gap / 2;
    const a = medianOf(u, h, (x) => x < -half - 0.5);
    const b = medianOf(u, h, (x) => x > half + 0.5);
    lines.push({ name: `P${seam.panels[0]}'s edge`, x: [-half, -half], y: [low, high], colour: "#e6194b" });
    lines.push({ name: `P${seam.panels[1]}'s edge (gap ${gap.toFixed(3)} mm)`, x: [half, half], y: [low, high], colour: "#f58231" });
    if (a !== null) lines.push({ name: `P${seam.panels[0]} top`, x: [Math.min(...u), -half], y: [a, a], colour: "#1f77b4" });
    if (b !== null) lines.push({ name: `P${seam.panels[1]} top`, x: [half, Math.max(...u)], y: [b, b], colour: "#2ca02c" });
  }
  return { title: `seam ${seam.seam} at ${section.along_mm} mm`, x_label: `across the seam (mm, P${seam.panels[0]} → P${seam.panels[1]})`, y_label: "height (mm)", lines, equal_axes: true };
}

function sectionText(section) {
  const sigma = (v) => (v === null || v === undefined ? "" : ` ± ${v.toFixed(3)}`);
  if (section.unmeasured) return `unmeasured here: ${section.unmeasured}`;
  const parts = [];
  if (section.gap_mm !== null && section.gap_mm !== undefined) parts.push(`gap ${section.gap_mm.toFixed(3)}${sigma(section.gap_sigma_mm)} mm (1σ)`);
  if (section.step_mm !== null && section.step_mm !== undefined) parts.push(`step ${section.step_mm.toFixed(3)} mm`);
  if (section.edges?.length) parts.push(`edges: ${section.edges.join(" / ")}`);
  return parts.join(" · ") || "nothing measured here";
}

// Each seam's cross-sections: pick the seam, slide along it; the plot is the section's.
function crossSectionsPanel(panel) {
  const seams = panel.seams.filter((s) => s.sections.length);
  if (!seams.length) return [el("p", { class: "muted" }, "no section to show")];
  const seamPick = el("select", { id: "section-seam", "aria-label": "seam" }, ...seams.map((s, k) => el("option", { value: String(k) }, `seam ${s.seam} (P${s.panels[0]}–P${s.panels[1]}, ${s.length_mm} mm)`)));
  const slider = el("input", { type: "range", id: "section-along", min: "0", value: "0", "aria-label": "position along the seam" });
  const where = el("span", { class: "muted", id: "section-where" });
  const text = el("p", { id: "section-values" });
  const holder = el("div", { class: "section-plot" });
  const draw = () => {
    const seam = seams[Number(seamPick.value)];
    slider.max = String(seam.sections.length - 1);
    const section = seam.sections[Math.min(Number(slider.value), seam.sections.length - 1)];
    where.textContent = `${section.along_mm} mm along (section ${Number(slider.value) + 1} of ${seam.sections.length})`;
    text.textContent = sectionText(section);
    holder.replaceChildren(...plotPanel(sectionPlot(seam, section)));
  };
  seamPick.addEventListener("change", () => { slider.value = "0"; draw(); });
  slider.addEventListener("input", draw);
  draw();
  return [el("div", { class: "section-tools" }, seamPick, slider, where), text, holder];
}

const THUMB_PX = 160;
const DEPTH_RAMP = ["#3b4cc0", "#dddddd", "#b40426"]; // below the surface → on it → above

function rampColour(t) { // t in 0..1 along DEPTH_RAMP
  const [a, b, f] = t < 0.5 ? [DEPTH_RAMP[0], DEPTH_RAMP[1], t * 2] : [DEPTH_RAMP[1], DEPTH_RAMP[2], t * 2 - 1];
  const mix = (i) => Math.round(parseInt(a.slice(i, i + 2), 16) * (1 - f) + parseInt(b.slice(i, i + 2), 16) * f);
  return `rgb(${mix(1)}, ${mix(3)}, ${mix(5)})`;
}

// Each surface finding from above: its surroundings' points coloured by their height off
// the surface, one scale per thumbnail (its colour bar under it).
function thumbnailsPanel(panel) {
  return [el("div", { class: "thumbs" }, ...panel.findings.map((f) => {
    const most = Math.max(0.01, ...f.h_mm.map(Math.abs));
    const px = (mm) => ((mm + f.reach_mm) / (2 * f.reach_mm)) * THUMB_PX;
    const picture = svg("svg", { viewBox: `0 0 ${THUMB_PX} ${THUMB_PX}`, class: "thumb", role: "img", "aria-label": f.label },
      svg("rect", { x: 0, y: 0, width: THUMB_PX, height: THUMB_PX, fill: "#0f1722" }),
      ...f.u_mm.map((u, i) => svg("circle", { cx: px(u), cy: THUMB_PX - px(f.v_mm[i]), r: 1.6, fill: rampColour((f.h_mm[i] / most + 1) / 2) })),
      svg("circle", { cx: THUMB_PX / 2, cy: THUMB_PX / 2, r: THUMB_PX / 4, fill: "none", stroke: "#1de9b6", "stroke-width": 1, "stroke-dasharray": "3 3" }));
    const bar = el("span", { class: "colour-bar" },
      el("span", {}, `−${most.toFixed(2)}`),
      el("span", { class: "colour-bar-ramp", style: `background: linear-gradient(90deg, ${DEPTH_RAMP.join(", ")})` }),
      el("span", {}, `+${most.toFixed(2)} mm`));
    return el("figure", { class: "thumb-box" }, picture, el("figcaption", {}, f.label, el("br"), el("span", { class: "muted" }, `${(2 * f.reach_mm).toFixed(0)} mm across · height off the surface `), bar));
  }))];
}

function panelNode(panel, inspectionId, urls) {
  const body = panel.type === "plot" ? plotPanel(panel)
    : panel.type === "figures" ? [figuresPanel(panel)]
      : panel.type === "pictures" ? picturePanel(panel, inspectionId, urls)
        : panel.type === "table" ? tablePanel(panel)
          : panel.type === "cross_sections" ? crossSectionsPanel(panel)
            : panel.type === "thumbnails" ? thumbnailsPanel(panel)
              : [el("p", { class: "muted" }, `a ${panel.type} panel this dashboard cannot draw yet`)];
  return el("section", { class: `card panel panel-${panel.type}`, dataset: { title: panel.title } }, el("h2", {}, panel.title), ...body);
}

// ---- the page ---------------------------------------------------------------------------

function fileList(artifacts, inspectionId) {
  if (!artifacts.length) return el("p", { class: "muted" }, "none");
  return el("ul", { class: "files" }, ...artifacts.map((a) => el(
    "li", {},
    el("button", { class: "link", dataset: { artifact: a.id }, onclick: () => api.download(inspectionId, a) }, a.name),
    el("span", { class: "muted" }, ` ${a.kind}, ${sizeText(a.size_bytes)}`),
  )));
}

// Draw job `jobId`'s page into `root`; returns a function that stops its live updates.
// `points`: the scene's point budget (default: the server's). Marks `vista:job-panels` when
// the results are drawn and `vista:job-scene` when the 3D scene is (the bench reads them).
export async function showJob(root, jobId, { onFinished, points } = {}) {
  const stop = new AbortController();
  const urls = [];
  const view = await api.jobView(jobId);
  const { job } = view;
  const bar = el("progress", { max: "1", value: String(job.progress) });
  const status = statusNode(job, { id: "job-status" });
  const message = el("p", { class: job.error ? "job-error" : job.warning ? "job-warning" : "muted", id: "job-message" }, job.error || job.message || "");
  const params = Object.entries(job.params || {});
  const logLine = (line) => el(
    "li", {}, el("span", { class: "muted" }, `${new Date(line.at).toLocaleTimeString()} · ${Math.round(line.progress * 100)} %${line.attempt > 1 ? ` · attempt ${line.attempt}` : ""}  `), line.message,
  );
  const log = el("ol", { class: "log", id: "job-log" }, ...view.log.map(logLine));
  let lastMessage = view.log.length ? view.log[view.log.length - 1].message : "";
  root.replaceChildren(...[
    el("div", { class: "run-page-head" },
      el("h1", {}, `${job.step} `, el("span", { class: "muted" }, `${job.kind} · job ${job.id} · run ${job.run_id}`)),
      el("a", { href: `#/inspections/${job.inspection_id}`, class: "back" }, "← the inspection")),
    el("section", { class: "card" }, el("h2", {}, "Progress"), el("div", { class: "job-progress" }, bar, status), message,
      el("p", { class: "muted" }, job.finished_at ? `finished ${new Date(job.finished_at).toLocaleString()}` : job.started_at ? `started ${new Date(job.started_at).toLocaleString()}` : "waiting"),
      el("details", { open: "" }, el("summary", {}, "Log"), view.log.length ? log : el("p", { class: "muted", id: "job-log-empty" }, "no messages yet"), )),
    el("div", { class: "run-columns" },
      el("section", { class: "card" }, el("h2", {}, "Inputs"), fileList(view.inputs, job.inspection_id),
        el("h2", {}, "Parameters"), params.length
          ? el("table", { class: "grid figures", id: "job-params" }, el("tbody", {}, ...params.map(([k, v]) => el("tr", {}, el("th", {}, k), el("td", {}, v === null ? "–" : typeof v === "object" ? JSON.stringify(v) : String(v))))))
          : el("p", { class: "muted" }, "defaults")),
      el("section", { class: "card", id: "job-outputs" }, el("h2", {}, "Outputs"), fileList(view.outputs, job.inspection_id))),
    view.note ? el("p", { class: "muted", id: "view-note" }, view.note) : null,
    view.scene ? el("section", { class: "card", id: "job-scene" }, el("h2", {}, "3D"), el("p", { class: "muted", id: "scene-note" }, "loading the scene…")) : null,
    el("div", { class: "panels", id: "panels" }, ...view.panels.map((p) => panelNode(p, job.inspection_id, urls))),
  ].filter((node) => node !== null));
  performance.mark("vista:job-panels");
  let player = null;
  if (view.scene) {
    player = new JobPlayer(root.querySelector("#job-scene"));
    api.jobScene(job.id, points).then((data) => player.load(data)).then((loaded) => {
      player.onDrawn = () => performance.mark("vista:job-scene");
      root.querySelector("#scene-note").textContent = loaded.frames > 1
        ? `${loaded.frames} frames: play, step or scrub; drag to turn, scroll to zoom`
        : "drag to turn, scroll to zoom";
    }).catch((error) => { root.querySelector("#scene-note").textContent = `the scene could not be shown: ${error.message}`; });
  }
  if (!["succeeded", "failed", "cancelled"].includes(job.status)) {
    followJob(job.id, (event, data) => {
      if (event === "progress") {
        bar.value = data.progress;
        status.textContent = data.status;
        status.className = `status-${data.status}`;
        message.textContent = data.error || data.message || "";
        if (data.message && data.message !== lastMessage) {
          lastMessage = data.message;
          root.querySelector("#job-log-empty")?.replaceWith(log);
          log.append(logLine({ at: new Date().toISOString(), progress: data.progress, attempt: data.attempts, message: data.message }));
        }
      } else if (event === "end" && onFinished) onFinished();
    }, stop.signal).catch(() => {});
  }
  return () => {
    stop.abort();
    if (player) player.dispose();
    for (const url of urls) URL.revokeObjectURL(url);
  };
}
