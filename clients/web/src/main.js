// vista's dashboard: sign in, inspections, the run timeline with live progress, defects
// with filters and sort, the 3D scene, judgments and consensus, and the feedback loop.
import { api, ApiError, followJob, session } from "./api.js";
import { el, statusNode } from "./dom.js";
import { canEdit, Files, FINISHED, jobButtons, RunForm, setUpNewInspection } from "./manage.js";
import { showJob } from "./runpage.js";
import { SceneView } from "./scene.js";
import { ToleranceForm } from "./tolerances.js";

const TYPES = [
  "gap", "step", "parallelism", "mismatch", "scratch", "dent", "bump", "color", "deviation",
];
// One distinct colour per type: the scene's rings use the same (supervisor/exports/scene.py).
const TYPE_COLORS = {
  gap: "#e6194b", step: "#f58231", parallelism: "#ffe119", mismatch: "#911eb4",
  scratch: "#4363d8", dent: "#3cb44b", bump: "#9a6324", color: "#f032e6", deviation: "#42d4f4",
};
// The scene's lines, each shown in the legend when the scene holds it.
const SCENE_LINES = [
  ["#59d9ff", "panel outline (P0, P1, …)", (facts) => facts.panels > 0],
  ["#ffffff", "seam", (facts) => facts.seams > (facts.unmeasured || 0)],
  ["#ff6b00", "unmeasured seam (hover it: why)", (facts) => facts.unmeasured > 0], // present.py UNMEASURED_RGBA
  ["#1de9b6", "selected", (facts) => facts.markers > 0], // scene.js SELECTED: no type's colour
];
const LIVE_POLL_MS = 3000;
const PREVIEW_POINTS = 100_000; // the scene's first cloud: every marker, fewer points
const $ = (selector) => document.querySelector(selector);

const state = {
  me: null,
  inspection: null,
  defects: new Map(), // the current findings: each physical defect once
  ended: new Map(), // findings a later measurement superseded or did not find again
  judgments: new Map(), // defect id → Map(user id → judgment)
  consensus: new Map(),
  cursor: null,
  selected: null,
  sortDescending: false,
  poll: null,
  jobStreams: new AbortController(),
  scene: null,
  sceneFacts: { markers: 0, panels: 0, seams: 0 }, // what the scene on show holds
  sceneRuns: [], // the measured runs, newest first: each has a scene of its own
  warnings: [], // the sync's: succeeded jobs that could not do all they were asked
  jobScenes: [], // the sync's: finished jobs with a 3D view of their own (perception runs)
  scenePick: null, // the run picked (null: the newest measured run)
  sceneEtag: null, // the scene's version in the last sync page: a new one reloads it
  stopJob: null, // ends the live updates of the job page on show
};

// ---- small helpers ------------------------------------------------------------------

function show(view) {
  for (const node of document.querySelectorAll(".view")) node.hidden = node.id !== `view-${view}`;
}

function number(value, digits = 3) {
  return value === null || value === undefined ? "–" : Number(value).toFixed(digits);
}

function unitText(unit) {
  return unit === "delta_e" ? "ΔE" : unit || "mm";
}

function valueOf(defect) {
  return { value: defect.value, tolerance: defect.tolerance, unit: unitText(defect.unit) };
}

const known = (x) => x !== null && x !== undefined;

// A gap narrower than its minimum is the one finding judged against a lower limit.
// out (beyond its limit by 2σ or more), within, or uncertain (within 2σ of it).
function stateOf(defect) {
  return defect.tolerance_state || (defect.severity === "info" ? "within" : "out");
}

// (the measurement's "uncertain", not a reviewer's verdict of that name)
const STATE_TEXT = { within: "within tolerance", uncertain: "uncertain measurement" };

function belowMinimum(defect) {
  return defect.type === "gap" && defect.severity !== "info" && known(defect.value) && defect.value < defect.tolerance;
}

// How far out of tolerance, as a multiple of the limit (over 1: out; a gap below its
// minimum by minimum / value): one scale for millimetres and ΔE alike.
function exceedance(defect) {
  const { value, tolerance } = valueOf(defect);
  if (!known(value) || !tolerance) return 0;
  const size = Math.abs(value);
  // a deviation below its band is judged by the band's lower (negative) end
  return belowMinimum(defect) ? tolerance / Math.max(size, 1e-6) : size / Math.abs(tolerance);
}

// The inspection's acceptance limits for this defect's type (its `limits`: the tolerances'
// own and the defaults where they are silent): both ends of a gap's range.
function limitsOf(defect) {
  const limits = state.inspection?.limits || {};
  const range = {
    gap: { min: limits.gap_min_mm, max: limits.gap_max_mm }, step: { max: limits.step_max_mm },
    parallelism: { max: limits.parallelism_max_mm }, mismatch: { max: limits.mismatch_max_mm },
    dent: { max: limits.dent_depth_mm }, bump: { max: limits.dent_depth_mm },
    scratch: { max: limits.scratch_depth_mm }, color: { max: limits.color_delta_e },
    deviation: { min: limits.profile_min_mm, max: limits.profile_max_mm },
  }[defect.type] || {};
  let { min = null, max = null } = range;
  if (belowMinimum(defect)) min = defect.tolerance; // what it was judged by
  else if (known(defect.tolerance) && !known(max)) max = defect.tolerance;
  const digits = defect.unit === "delta_e" ? 1 : 2;
  const unit = unitText(defect.unit);
  if (known(min) && known(max)) return `${number(min, digits)}–${number(max, digits)} ${unit}`;
  if (known(min)) return `≥ ${number(min, digits)} ${unit}`;
  const size = defect.type === "step" ? "|step| " : ""; // a step is judged by its size either way
  return known(max) ? `${size}≤ ${number(max, digits)} ${unit}` : "–";
}

// What a signed value means (contract/tolerances.py sign_text): a seam's step is its
// second panel's top over its first's.
function signOf(defect) {
  const panels = defect.measurements?.panels;
  const { value } = valueOf(defect);
  if (defect.type !== "step" || !panels || !value) return "";
  return ` (P${panels[1]} ${value > 0 ? "above" : "below"} P${panels[0]})`;
}

// Where the value stands against the limit it was judged by.
function relationText(defect) {
  const { value, tolerance, unit } = valueOf(defect);
  if (!known(value) || !known(tolerance)) return "";
  const sigma = defect.measurements?.sigma_mm;
  if (stateOf(defect) === "uncertain") return `within 2σ of the limit (1σ ${number(sigma)} ${unit}): measure again`;
  if (defect.severity === "info") return "within tolerance";
  if (belowMinimum(defect)) return `${number(tolerance - value)} ${unit} below the minimum`;
  return `${number(Math.abs(value) - tolerance)} ${unit} over the limit`;
}

function consensusText(consensus) {
  if (!consensus || !consensus.total) return "not judged";
  const top = consensus.majority ? `${consensus.counts[consensus.majority]}/${consensus.total} ${consensus.majority}` : `split ${consensus.total}`;
  return consensus.needs_review ? `${top} · needs review` : top;
}

async function guarded(action) {
  try {
    return await action();
  } catch (error) {
    if (error instanceof ApiError && error.status === 401) {
      session.token = null;
      location.hash = "#/sign-in";
      return undefined;
    }
    throw error;
  }
}

// ---- sign-in and inspections ----------------------------------------------------------

setUpNewInspection();
const files = new Files(() => {
  runForm.drawKind();
  live(); // a first cloud is drawn now, not at the next poll
});
const runForm = new RunForm(files, () => {
  for (const tab of document.querySelectorAll("[role=tab]")) if (tab.dataset.tab === "timeline") tab.click();
  $("#run-box").open = false;
  loadTimeline();
});

$("#sign-in-form").addEventListener("submit", async (event) => {
  event.preventDefault();
  const form = new FormData(event.target);
  $("#sign-in-error").textContent = "";
  try {
    const answer = await api.signIn(form.get("username"), form.get("password"));
    session.token = answer.access_token;
    if (!location.hash || location.hash === "#/sign-in") location.hash = "#/inspections";
    else route();
  } catch (error) {
    $("#sign-in-error").textContent = error.message;
  }
});

$("#sign-out").addEventListener("click", async () => {
  // The server revokes the token, so a copy of it (another tab, a leaked log) stops too.
  try {
    await api.signOut();
  } catch {
    // already expired or revoked: signing out here is all that is left to do
  }
  session.token = null;
  state.me = null;
  resetInspection(); // the next person sees nothing of this one's page, nor its buttons
  state.inspection = null;
  $("#sign-in-form").reset(); // the password must not wait in the form for the next person
  location.hash = "#/sign-in";
});

async function showInspections() {
  show("inspections");
  $("#crumbs").textContent = "inspections";
  const page = await guarded(api.inspections);
  if (!page) return;
  const body = $("#inspection-table tbody");
  body.replaceChildren(...page.items.map((i) => el(
    "tr", { onclick: () => { location.hash = `#/inspections/${i.id}`; }, dataset: { id: i.id } },
    el("td", {}, String(i.id)), el("td", {}, i.title), el("td", {}, i.aircraft || "–"),
    el("td", {}, i.area), el("td", {}, i.status), el("td", {}, new Date(i.created_at).toLocaleString()),
  )));
  $("#inspections-empty").hidden = page.items.length > 0;
}

// ---- one inspection -----------------------------------------------------------------------

function resetInspection() {
  clearInterval(state.poll);
  state.jobStreams.abort();
  state.jobStreams = new AbortController();
  state.defects.clear();
  state.ended.clear();
  state.judgments.clear();
  state.consensus.clear();
  state.cursor = null;
  state.selected = null;
  state.sceneFacts = { markers: 0, panels: 0, seams: 0 };
  state.sceneRuns = [];
  state.warnings = [];
  state.jobScenes = [];
  state.scenePick = null;
  state.sceneEtag = null;
  $("#detail").hidden = true;
  // Rows drawn for the last page (and the last person: their buttons) go with it, so a
  // page opened next never shows them while its own are fetched.
  $("#timeline").replaceChildren();
  $("#runs-error").textContent = "";
  $("#artifact-table tbody").replaceChildren();
}

function fold(page) {
  if (page.inspection) state.inspection = page.inspection;
  for (const defect of page.defects) {
    if (defect.ended) { // measured again (its judgments travel on) or not found again
      state.defects.delete(defect.id);
      state.ended.set(defect.id, defect);
      if (state.selected === defect.id && defect.superseded_by_id) state.selected = defect.superseded_by_id;
    } else state.defects.set(defect.id, defect);
  }
  for (const judgment of page.judgments) {
    if (!state.judgments.has(judgment.defect_id)) state.judgments.set(judgment.defect_id, new Map());
    const byUser = state.judgments.get(judgment.defect_id);
    const held = byUser.get(judgment.user_id); // the sync carries no history: keep the one read
    const history = held?.revision === judgment.revision ? held.history : undefined;
    byUser.set(judgment.user_id, history ? { ...judgment, history } : judgment);
  }
  for (const consensus of page.consensus) state.consensus.set(consensus.defect_id, consensus);
  state.warnings = page.warnings || [];
  state.jobScenes = page.job_scenes || [];
  state.cursor = page.next_cursor;
  return page;
}

// The warnings of the run on show (the newest measured run's, unless one is picked): what
// its jobs could not do — seams a measurement left unmeasured, and why.
function shownWarnings() {
  const run = shownRun();
  return (state.warnings || []).filter((w) => run === null || w.run_id === run);
}

function renderWarnings() {
  const warnings = shownWarnings();
  $("#run-warning").hidden = warnings.length === 0;
  $("#run-warning").replaceChildren(...warnings.map((w) => el("p", {}, el("b", {}, `run ${w.run_id}, ${w.step}: `), w.warning)));
}

async function pull() {
  let page;
  do page = fold(await api.sync(state.inspection.id, state.cursor)); while (page.more);
  return page;
}

async function showInspection(id, defectId) {
  if (state.inspection?.id !== id || !state.cursor) {
    resetInspection();
    state.inspection = { id };
    show("inspection");
    // A light preview of the scene downloads while the defects sync: the two are the first
    // paint. The full cloud follows.
    const preview = api.scene(id, PREVIEW_POINTS);
    preview.catch(() => {}); // its failure is shown by loadScene, not as an unhandled rejection
    const syncing = guarded(pull);
    // WebGL starts up (a few hundred ms on a software renderer) while both are on their way.
    if (!state.scene) {
      const pick = (defectId) => { location.hash = `#/inspections/${state.inspection.id}/defects/${defectId}`; };
      state.scene = new SceneView($("#scene"), pick, { scaleBar: $("#scale-bar") });
      // on a narrow scene the legend starts folded: it would cover the part
      $("#legend-box").open = $("#scene").clientWidth >= 720;
    }
    const page = await syncing;
    if (!page) return;
    state.sceneEtag = page.scene_etag;
    renderCrumbs();
    renderList();
    performance.mark("vista:list-drawn");
    loadScene(id, preview);
    loadSceneRuns(id);
    loadTimeline();
    loadFeedback();
    toleranceForm.open(state.inspection, state.me).catch((error) => { $("#tolerance-error").textContent = error.message; });
    if (canEdit(state.me)) runForm.open(id).catch((error) => { $("#run-error").textContent = error.message; });
    else files.open(id).catch(() => {});
    state.poll = setInterval(live, LIVE_POLL_MS);
  }
  show("inspection");
  if (defectId) select(defectId, true);
}

function renderCrumbs() {
  const { title, status } = state.inspection;
  // never a plain status while the run on show left seams unmeasured
  const unmeasured = shownWarnings().reduce((n, w) => n + (w.unmeasured_seams || 0), 0);
  const warned = shownWarnings().length > 0;
  const text = unmeasured ? `${status} · ${unmeasured} seam${unmeasured === 1 ? "" : "s"} unmeasured` : warned ? `${status} · warning` : status;
  $("#crumbs").replaceChildren(
    el("a", { href: "#/inspections" }, "inspections"), ` / ${title} `,
    el("span", { class: `inspection-status${warned ? " status-warning" : ""}`, id: "inspection-status" }, text),
  );
  renderWarnings();
}

async function live() {
  try {
    const before = state.cursor;
    const status = state.inspection.status;
    const warnings = JSON.stringify(state.warnings);
    const page = await pull();
    if (state.inspection.status !== status || JSON.stringify(state.warnings) !== warnings) {
      renderCrumbs();
      loadTimeline();
    }
    if (state.cursor !== before && (page.defects.length || page.judgments.length)) {
      renderList();
      if (state.selected) renderDetail();
      if (page.judgments.some((j) => j.defect_id === state.selected)) refreshJudgments(state.selected);
      loadFeedback();
    }
    if (page.scene_etag !== state.sceneEtag) { // something the scene shows changed
      state.sceneEtag = page.scene_etag;
      const newest = state.sceneRuns[0]?.job_id;
      await loadSceneRuns(state.inspection.id);
      // the ETag follows the geometry only (a measurement, a cloud, a finding added by
      // hand, markers moved; not a judgment): the scene on show is drawn again
      const measured = state.sceneRuns[0]?.job_id !== newest;
      if (state.scenePick === null || measured) {
        loadScene(state.inspection.id, api.scene(state.inspection.id, PREVIEW_POINTS, state.scenePick ?? undefined));
      }
    }
  } catch { /* offline for a moment: the next poll catches up */ }
}

// ---- defect list ------------------------------------------------------------------------

for (const type of TYPES) {
  $("#filter-type").append(el("option", { value: type }, type));
  $("#new-type").append(el("option", { value: type }, type));
  $("#new-finding-type").append(el("option", { value: type }, type));
}
for (const id of ["#filter-type", "#filter-status", "#filter-severity", "#filter-consensus"]) {
  $(id).addEventListener("change", renderList);
}
function setSortDescending(descending) {
  state.sortDescending = descending;
  $("#sort-direction").textContent = descending ? "↑" : "↓";
}
$("#sort-direction").addEventListener("click", () => {
  setSortDescending(!state.sortDescending);
  renderList();
});
// How far out of tolerance reads worst first.
$("#sort").addEventListener("change", () => {
  setSortDescending($("#sort").value === "value");
  renderList();
});

function visibleDefects() {
  const type = $("#filter-type").value;
  const status = $("#filter-status").value;
  const severity = $("#filter-severity").value;
  const wanted = $("#filter-consensus").value;
  const run = shownRun();
  const rows = shownPool(run).filter((d) => {
    const consensus = state.consensus.get(d.id);
    if (!ofShownRun(d, run)) return false; // another run's scene
    if (type && d.type !== type) return false;
    if (status && d.status !== status) return false;
    if ((severity === "out" || severity === "uncertain") && stateOf(d) !== severity) return false;
    if (severity && !["out", "uncertain"].includes(severity) && d.severity !== severity) return false;
    if (wanted === "none" && consensus?.total) return false;
    if (wanted === "review" && !consensus?.needs_review) return false;
    if (["confirmed", "rejected", "reclassified"].includes(wanted) && consensus?.majority !== wanted) return false;
    return true;
  });
  const keys = {
    id: (d) => d.id,
    type: (d) => TYPES.indexOf(d.type) * 1e9 + d.id,
    value: (d) => exceedance(d),
    status: (d) => d.status,
    consensus: (d) => state.consensus.get(d.id)?.agreement ?? -1,
  };
  const key = keys[$("#sort").value];
  rows.sort((a, b) => {
    const ka = key(a);
    const kb = key(b);
    return (ka < kb ? -1 : ka > kb ? 1 : a.id - b.id) * (state.sortDescending ? -1 : 1);
  });
  return rows;
}

// The findings a run's scene shows: the current ones, and for an earlier run picked, its
// own findings that a later measurement ended (history: what it found then).
function shownPool(run) {
  const current = [...state.defects.values()];
  if (run === null || run === state.sceneRuns[0]?.run_id) return current;
  return [...current, ...[...state.ended.values()].filter((d) => d.run_id === run)];
}

function endedText(defect) {
  if (defect.ended === "superseded") return `measured again by run ${defect.ended_run_id}: #${defect.superseded_by_id}`;
  return `not found again by run ${defect.ended_run_id}`;
}

function rowFor(defect) {
  const { value, unit } = valueOf(defect);
  const text = `#${defect.id} ${defect.type} ${number(value)} ${unit}`;
  const title = `${text} · limits ${limitsOf(defect)} · ${relationText(defect)} · ${defect.severity} · ${defect.status}`;
  return el(
    "div",
    {
      class: "row", role: "option", dataset: { id: defect.id },
      "aria-selected": String(defect.id === state.selected),
      onclick: () => { location.hash = `#/inspections/${state.inspection.id}/defects/${defect.id}`; },
    },
    el("span", { class: "dot", style: `background:${TYPE_COLORS[defect.type]}` }),
    el("span", { class: "what", title }, text),
    stateOf(defect) === "uncertain"
      ? el("span", { class: "severity severity-uncertain", title: defect.measurements?.advice || "" }, "uncertain")
      : el("span", { class: `severity severity-${defect.severity}` }, defect.severity === "info" ? "within" : defect.severity),
    el("span", { class: "verdict" }, defect.ended ? endedText(defect) : consensusText(state.consensus.get(defect.id))),
  );
}

function renderList() {
  const rows = visibleDefects();
  $("#defect-list").replaceChildren(...rows.map(rowFor));
  const run = shownRun();
  const ofRun = run === null ? "" : ` · run ${run}'s and those added by hand`;
  const current = rows.filter((d) => !d.ended).length;
  const history = rows.length - current;
  const earlier = history ? ` (+ ${history} it found that later runs ended)` : "";
  $("#defect-count").textContent = `${current} of ${state.defects.size} findings${earlier}${ofRun}`;
  const perception = perceptionOnly();
  $("#defects-empty").hidden = state.defects.size > 0 || perception;
  $("#perception-note").hidden = !perception;
  renderLegend();
}

// An inspection of perception runs only (depth, odometry, tracking): no part measured, no
// finding; the page does not ask for a measurement.
function perceptionOnly() {
  return state.defects.size === 0 && state.sceneRuns.length === 0 && state.jobScenes.length > 0;
}

// The scene's legend: the colour of every type on show, and of the lines.
function renderLegend() {
  const run = shownRun();
  const shown = shownPool(run).filter((d) => ofShownRun(d, run));
  const types = TYPES.filter((t) => shown.some((d) => d.type === t));
  const entry = (colour, text, shape) => el("li", {}, el("span", { class: `swatch ${shape}`, style: `--swatch:${colour}` }), text);
  $("#legend").replaceChildren(
    ...types.map((t) => entry(TYPE_COLORS[t], t, "ring")),
    ...SCENE_LINES.filter(([, , shown]) => shown(state.sceneFacts)).map(([colour, text]) => entry(colour, text, "line")),
  );
}

// ---- selection, detail and judging ------------------------------------------------------

function findingOf(defectId) {
  return state.defects.get(defectId) || state.ended.get(defectId);
}

function select(defectId, fly) {
  if (!findingOf(defectId)) return;
  const run = findingOf(defectId).run_id;
  if (run !== null && run !== shownRun() && state.sceneRuns.some((r) => r.run_id === run)) {
    pickSceneRun(run); // a finding is shown on the cloud its run measured
  }
  if (state.selected !== defectId) resetJudgeForm(defectId);
  state.selected = defectId;
  for (const row of document.querySelectorAll("#defect-list .row")) {
    row.setAttribute("aria-selected", String(Number(row.dataset.id) === defectId));
  }
  document.querySelector(`#defect-list .row[data-id="${defectId}"]`)?.scrollIntoView({ block: "nearest" });
  state.scene?.select(defectId, fly, seamOf(defectId));
  renderDetail();
  refreshJudgments(defectId);
}

function deselect() {
  state.selected = null;
  $("#detail").hidden = true;
  state.scene?.select(null, false, null);
  for (const row of document.querySelectorAll("#defect-list .row")) row.setAttribute("aria-selected", "false");
  if (/\/defects\/\d+$/.test(location.hash)) history.replaceState(null, "", `#/inspections/${state.inspection.id}`);
}

function seamOf(defectId) {
  const seam = findingOf(defectId)?.measurements?.seam;
  return known(seam) ? seam : null;
}

// The judging form belongs to the selected defect: on a new selection it shows my own
// judgment of that defect (its comment and new type), or nothing.
function resetJudgeForm(defectId) {
  const mine = state.judgments.get(defectId)?.get(state.me?.id);
  $("#comment").value = mine?.comment || "";
  // "Reclassify as" offers the other types: the finding's own is no reclassification
  const own = findingOf(defectId).type;
  for (const option of $("#new-type").options) option.disabled = option.value === own;
  $("#new-type").value = mine?.new_type || TYPES.find((t) => t !== own);
  $("#judge-error").textContent = "";
}

// Where a finding is, by the ids the scene labels (P0, P1, …): a seam's step is its
// second panel's top over its first's; a place on a seam is its distance from the start.
function placeOf(measurements) {
  const { seam, panels, panel, junction, seams, along_mm: along, length_mm: length } = measurements;
  const facts = [];
  if (Array.isArray(panels) && panels.length === 2) {
    facts.push(["seam", `${seam}, between P${panels[0]} and P${panels[1]} (step = P${panels[1]}'s top over P${panels[0]}'s)`]);
    if (known(along)) facts.push(["along the seam", `${number(along, 1)} mm from its start${known(length) ? ` (of ${number(length, 1)} mm)` : ""}`]);
  } else if (known(panel)) facts.push(["panel", `P${panel}`]);
  else if (known(junction)) facts.push(["junction", `${junction}${Array.isArray(seams) ? ` (seams ${seams.join(", ")})` : ""}`]);
  return facts;
}

function renderDetail() {
  const defect = findingOf(state.selected);
  if (!defect) return;
  const { value, unit } = valueOf(defect);
  $("#detail").hidden = false;
  $("#detail-title").textContent = `#${defect.id} ${defect.type} — ${STATE_TEXT[stateOf(defect)] || defect.severity}, ${defect.ended ? endedText(defect) : defect.status}`;
  const relation = relationText(defect);
  const facts = [
    ["value", `${number(value)} ${unit}${signOf(defect)}${relation ? ` — ${relation}` : ""}`], ["limits", limitsOf(defect)],
    ["confidence", number(defect.confidence, 2)], ["extent", `${number(defect.extent_mm, 1)} mm`],
    ...(known(defect.measurements?.sigma_mm) ? [["uncertainty", `± ${number(defect.measurements.sigma_mm)} ${unit} (1σ)`]] : []),
    ...(defect.measurements?.advice ? [["advice", defect.measurements.advice]] : []),
    ...placeOf(defect.measurements || {}),
    ["coordinates", `${defect.location_mm.map((c) => number(c, 1)).join(", ")} mm (base frame)`],
    // a finding the tolerances' change could not judge again says so, and offers the run
    ...(defect.measurements?.stale ? [["stale", el("span", {}, defect.measurements.stale, " ", remeasureButton(defect))]] : []),
  ];
  $("#detail-facts").replaceChildren(...facts.flatMap(([k, v]) => [el("dt", {}, k), el("dd", {}, v)]));
  const consensus = state.consensus.get(defect.id);
  $("#consensus").textContent = `Consensus: ${consensusText(consensus)}`;
  $("#consensus").dataset.total = String(consensus?.total || 0);
  const others = [...(state.judgments.get(defect.id)?.values() || [])];
  const verdictText = (j) => `${j.verdict}${j.new_type ? ` → ${j.new_type}` : ""}`;
  // earlier revisions of a judgment, newest first, under it (GET /defects/{id}/judgments);
  // one left open stays open when the pane is drawn again
  const opened = new Set([...document.querySelectorAll("#judgments details.history[open]")].map((d) => d.closest("li").dataset.user));
  const history = (j) => (j.history?.length > 1 ? el(
    "details", { class: "history", ...(opened.has(j.username) ? { open: "" } : {}) }, el("summary", {}, `${j.history.length} revisions`),
    el("ol", { reversed: "" }, ...j.history.slice().reverse().map((r) => el(
      "li", { dataset: { revision: r.revision } },
      `${verdictText(r)}${r.comment ? ` — ${r.comment}` : ""} `,
      el("span", { class: "muted" }, new Date(r.created_at).toLocaleString()),
    ))),
  ) : null);
  $("#judgments").replaceChildren(...others.map((j) => el(
    "li", { dataset: { user: j.username } },
    el("b", {}, j.username), ` ${verdictText(j)}`,
    j.comment ? el("span", { class: "muted" }, ` — ${j.comment}`) : null,
    el("span", { class: "muted" }, ` (rev ${j.revision}, ${new Date(j.updated_at).toLocaleString()})`),
    j.judged_on_run_id ? el("span", { class: "judged-on" }, ` judged on run ${j.judged_on_run_id}`) : null,
    history(j),
  )));
  const mine = state.judgments.get(defect.id)?.get(state.me?.id);
  for (const button of document.querySelectorAll(".verdicts button")) {
    button.classList.toggle("active", mine?.verdict === button.dataset.verdict);
  }
  const canJudge = canEdit(state.me) && !defect.ended; // an ended finding is history
  for (const button of document.querySelectorAll(".verdicts button")) button.disabled = !canJudge;
  renderNotes(defect);
  renderLineage(defect);
}

// A finding measured more than once: each run's finding in its line, and how it ended.
async function renderLineage(defect) {
  const measuredAgain = defect.supersedes_id || defect.ended;
  $("#lineage").hidden = !measuredAgain;
  if (!measuredAgain) return;
  const line = await guarded(() => api.defectHistory(defect.id));
  if (!line || state.selected !== defect.id) return;
  const judgedOn = (run) => line.judgments.filter((j) => j.judged_on_run_id === run);
  $("#lineage-steps").replaceChildren(...line.steps.map((step) => el(
    "li", { dataset: { id: step.id } },
    el("b", {}, `run ${step.run_id}${step.run_name ? ` (${step.run_name})` : ""}`),
    ` #${step.id} ${step.type} ${number(step.measurements?.value ?? step.value_mm)} ${unitText(step.measurements?.unit)} · ${step.severity}, ${step.status}`,
    el("span", { class: "muted" }, step.ended ? ` — ${endedText({ ...step, superseded_by_id: line.steps.find((s) => s.run_id === step.ended_run_id)?.id ?? "?" })}` : " — current"),
    ...judgedOn(step.run_id).map((j) => el("div", { class: "muted" }, `${j.username}: ${j.verdict}${j.new_type ? ` → ${j.new_type}` : ""}${j.comment ? ` — ${j.comment}` : ""} (rev ${j.revision})`)),
  )));
}

// One click measures the finding's cloud again, as its run did, by today's tolerances.
function remeasureButton(defect) {
  const measured = state.sceneRuns.find((r) => r.run_id === defect.run_id);
  if (!measured || !canEdit(state.me)) return null;
  return el("button", {
    id: "remeasure",
    onclick: async (event) => {
      event.currentTarget.disabled = true;
      try {
        const job = await api.job(measured.job_id);
        const step = { name: job.step, kind: job.kind, inputs: [measured.cloud_artifact_id], params: job.params };
        await api.createRun(state.inspection.id, { name: `measure again (run ${defect.run_id})`, steps: [step] });
        $("#judge-error").textContent = "";
        for (const tab of document.querySelectorAll("[role=tab]")) if (tab.dataset.tab === "timeline") tab.click();
        loadTimeline();
      } catch (error) {
        $("#judge-error").textContent = error.message;
      }
    },
  }, "Measure again");
}

async function refreshJudgments(defectId) {
  const listing = await guarded(() => api.judgments(defectId));
  if (!listing || defectId !== state.selected) return;
  state.judgments.set(defectId, new Map(listing.judgments.map((j) => [j.user_id, j])));
  state.consensus.set(defectId, { defect_id: defectId, ...listing.consensus });
  renderDetail();
}

for (const button of document.querySelectorAll(".verdicts button")) {
  button.addEventListener("click", async () => {
    const verdict = button.dataset.verdict;
    const id = state.selected; // the answer may arrive after another defect is selected
    const body = { verdict, comment: $("#comment").value };
    if (verdict === "reclassified") body.new_type = $("#new-type").value;
    $("#judge-error").textContent = "";
    try {
      const answer = await guarded(() => api.judge(id, body));
      if (!answer) return;
      if (!state.judgments.has(id)) state.judgments.set(id, new Map());
      state.judgments.get(id).set(answer.judgment.user_id, answer.judgment);
      state.consensus.set(id, { defect_id: id, ...answer.consensus });
      if (id === state.selected) renderDetail();
      refreshJudgments(id); // with the revisions before this one
      const cell = document.querySelector(`#defect-list .row[data-id="${id}"] .verdict`);
      if (cell) cell.textContent = consensusText(answer.consensus); // unless filtered out
    } catch (error) {
      if (id === state.selected) $("#judge-error").textContent = error.message;
    }
  });
}

// ---- findings by hand and notes -------------------------------------------------------------

// "Add a finding": the next click on the part places it (a point of the cloud), then the
// form asks what it is.
function setPlacing(on) {
  const button = $("#add-finding");
  button.setAttribute("aria-pressed", String(on));
  button.textContent = on ? "Click a point of the part (Esc: cancel)" : "Add a finding";
  if (state.scene) state.scene.placing = on ? placeFinding : null;
}

function placeFinding(pointMm, normal) {
  setPlacing(false);
  state.newFinding = { location_mm: pointMm, normal };
  $("#new-finding-where").textContent = `at ${pointMm.map((c) => number(c, 1)).join(", ")} mm (base frame), facing the view`;
  $("#new-finding-error").textContent = "";
  $("#new-finding").hidden = false;
  $("#new-finding-type").focus();
}

$("#add-finding").addEventListener("click", () => setPlacing($("#add-finding").getAttribute("aria-pressed") !== "true"));
document.addEventListener("keydown", (event) => { if (event.key === "Escape") setPlacing(false); });
$("#new-finding-cancel").addEventListener("click", () => { $("#new-finding").hidden = true; });
$("#new-finding").addEventListener("submit", async (event) => {
  event.preventDefault();
  const value = $("#new-finding-value").value.trim();
  const note = $("#new-finding-note").value.trim();
  const body = {
    inspection_id: state.inspection.id, type: $("#new-finding-type").value, severity: $("#new-finding-severity").value,
    ...state.newFinding, ...(value ? { value_mm: Number(value) } : {}), ...(note ? { note } : {}),
  };
  try {
    const made = await guarded(() => api.reportDefect(body));
    if (!made) return;
    $("#new-finding").hidden = true;
    event.target.reset();
    await pull();
    renderList();
    location.hash = `#/inspections/${state.inspection.id}/defects/${made.id}`;
  } catch (error) {
    $("#new-finding-error").textContent = error.message;
  }
});

function renderNotes(defect) {
  const notes = defect.notes || [];
  $("#notes").replaceChildren(...notes.map((n) => el(
    "li", {}, el("b", {}, n.username || "someone removed"), ` ${n.text} `, el("span", { class: "muted" }, new Date(n.at).toLocaleString()),
  )));
  $("#notes-box").hidden = !notes.length && !canEdit(state.me);
}

$("#note-form").addEventListener("submit", async (event) => {
  event.preventDefault();
  const id = state.selected;
  const text = $("#note-text").value.trim();
  if (!text) return;
  $("#note-error").textContent = "";
  try {
    const defect = await guarded(() => api.annotate(id, text));
    if (!defect) return;
    $("#note-text").value = "";
    await pull();
    if (id === state.selected) renderDetail();
  } catch (error) {
    $("#note-error").textContent = error.message;
  }
});

// ---- scene --------------------------------------------------------------------------------

async function loadScene(id, preview) {
  const status = $("#scene-status");
  status.textContent = "loading the scene…";
  $("#scene-empty").hidden = true;
  const hint = "drag to orbit, click a marker to select it";
  // The measured panels are outlined and labelled P0, P1, …: the ids findings refer to.
  const panels = (n) => (n === 1 ? "1 panel (P0)" : `${n} panels (P0…)`);
  const shown = (scene) => (perceptionOnly()
    ? `no part measured here${scene.points ? " (the newest cloud is drawn)" : ""}: each perception run's 3D view is on its page (Runs tab)`
    : `${scene.markers} markers · ${scene.panels ? panels(scene.panels) : "no measured panels"}`);
  try {
    const first = await showScene(id, preview, { frame: true, mark: "vista:scene-drawn" });
    if (!first) return;
    state.sceneFacts = first;
    renderLegend();
    const chosen = state.defects.get(state.selected);
    if (chosen && !ofShownRun(chosen, shownRun())) deselect(); // another run's finding
    if (!first.points && perceptionOnly()) {
      $("#scene-empty").textContent = "This inspection holds perception runs (depth, odometry, tracking): no part to draw here. Each run's page (Runs tab, click a job) shows its results in 3D.";
      $("#scene-empty").hidden = false;
    } else if (!first.points) {
      $("#scene-empty").textContent = "No point cloud in this inspection yet. Upload one as an artifact of kind \"cloud\", or run calibrate → stitch → measure on the scans (see the Runs tab); the measured panels, seams and defects are drawn on it.";
      $("#scene-empty").hidden = false;
    }
    $(".scale").hidden = !first.points;
    if (state.selected) state.scene.select(state.selected, true, seamOf(state.selected));
    if (first.points < PREVIEW_POINTS) {
      status.textContent = `${shown(first)} · ${hint}`;
      return;
    }
    status.textContent = `${shown(first)} · loading the full cloud… · ${hint}`;
    const full = await showScene(id, api.scene(id, undefined, state.scenePick ?? undefined), { frame: false, mark: "vista:scene-full-drawn" });
    if (full) status.textContent = `${shown(full)} · ${hint}`;
  } catch (error) {
    status.textContent = `the scene could not be shown: ${error.message}`;
  }
}

// The run whose scene is on show: the one picked, else the newest measured (null: none).
function shownRun() {
  return state.scenePick ?? state.sceneRuns[0]?.run_id ?? null;
}

// A finding is on that run's scene when the run found it, or a reviewer added it by hand.
function ofShownRun(defect, run) {
  return run === null || defect.run_id === null || defect.run_id === run;
}

async function loadSceneRuns(id) {
  try {
    const runs = await api.sceneRuns(id);
    if (state.inspection?.id !== id) return;
    state.sceneRuns = runs;
    if (state.scenePick !== null && !runs.some((r) => r.run_id === state.scenePick)) state.scenePick = null;
    const label = (r) => `run ${r.run_id}${r.run_name ? ` (${r.run_name})` : ""} · ${r.step} of ${r.cloud_name} · ${new Date(r.finished_at).toLocaleString()}`;
    $("#scene-run").replaceChildren(
      el("option", { value: "" }, runs.length ? `the newest: ${label(runs[0])}` : "no measured run"),
      ...runs.map((r) => el("option", { value: String(r.run_id) }, label(r))),
    );
    $("#scene-run").value = state.scenePick === null ? "" : String(state.scenePick);
    $("#scene-run-box").hidden = runs.length === 0;
    renderList();
    if (state.inspection.title !== undefined) renderCrumbs(); // the run on show's warnings
  } catch { /* the picker stays as it was; the next change tries again */ }
}

function pickSceneRun(run) {
  state.scenePick = run;
  $("#scene-run").value = run === null ? "" : String(run);
  renderList();
  renderCrumbs();
  loadScene(state.inspection.id, api.scene(state.inspection.id, PREVIEW_POINTS, run ?? undefined));
}

$("#scene-run").addEventListener("change", () => {
  const value = $("#scene-run").value;
  pickSceneRun(value ? Number(value) : null);
});

// The scene's GLB drawn in place of the last one, unless the user has moved on meanwhile.
async function showScene(id, pending, { frame, mark }) {
  const bytes = await (await pending).arrayBuffer();
  const isCurrent = () => state.inspection?.id === id;
  if (!isCurrent()) return null;
  performance.mark(`${mark}:fetched`);
  const loaded = await state.scene.load(bytes, { frame, mark, isCurrent });
  performance.mark(`${mark}:parsed`);
  return loaded;
}

// ---- run timeline ----------------------------------------------------------------------

function jobRow(job) {
  const bar = el("progress", { max: "1", value: String(job.progress) });
  const status = statusNode(job);
  const message = el("div", { class: job.error ? "job-error" : job.warning ? "job-warning" : "job-message muted" }, job.error || job.message || "");
  const name = el("a", { class: "job-step", title: `job ${job.id}: its page`, href: `#/inspections/${job.inspection_id}/jobs/${job.id}` }, `${job.step} `, el("span", { class: "muted" }, job.kind));
  const refused = (error) => { $("#runs-error").textContent = `job ${job.id}: ${error.message}`; };
  const actions = el("span", { class: "job-actions" }, ...jobButtons(job, state.me, loadTimeline, refused));
  return { node: el("div", { class: "job", dataset: { job: job.id } }, name, bar, el("span", {}, status, actions), message), bar, status, message };
}

async function loadTimeline() {
  const page = await guarded(() => api.runs(state.inspection.id));
  if (!page) return;
  $("#runs-error").textContent = "";
  state.jobStreams.abort(); // the rows drawn before stop following their jobs
  state.jobStreams = new AbortController();
  $("#timeline").replaceChildren(...page.items.map((run) => {
    const rows = run.jobs.map((job) => {
      const row = jobRow(job);
      if (!FINISHED.includes(job.status)) {
        followJob(job.id, (event, data) => {
          if (event !== "progress") return;
          row.bar.value = data.progress;
          row.status.textContent = data.status;
          row.status.className = `status-${data.status}`;
          row.message.textContent = data.error || data.message || "";
          row.message.className = data.error ? "job-error" : "job-message muted";
          if (FINISHED.includes(data.status)) loadTimeline(); // its buttons change: retry

        }, state.jobStreams.signal).catch(() => {});
      }
      return row.node;
    });
    return el(
      "li", {},
      el("div", { class: "run-head" }, el("b", {}, `run ${run.id} ${run.name || ""}`), statusNode(run), el("span", { class: "muted" }, new Date(run.created_at).toLocaleString())),
      ...rows,
    );
  }));
  $("#runs-empty").hidden = page.items.length > 0;
}

// A job's own page (runpage.js): reached from its row in the Runs tab.
async function showJobPage(inspectionId, jobId, points) {
  resetInspection();
  state.inspection = null;
  show("job");
  $("#crumbs").replaceChildren(
    el("a", { href: "#/inspections" }, "inspections"), " / ",
    el("a", { href: `#/inspections/${inspectionId}` }, `inspection ${inspectionId}`), ` / job ${jobId}`,
  );
  const root = $("#job-page");
  root.replaceChildren(el("p", { class: "muted" }, "loading…"));
  try {
    state.stopJob = await guarded(() => showJob(root, jobId, { onFinished: () => route(), points }));
  } catch (error) {
    root.replaceChildren(el("p", { class: "error", role: "alert" }, `job ${jobId}: ${error.message}`));
  }
}

// ---- tolerances --------------------------------------------------------------------------

const toleranceForm = new ToleranceForm((inspection) => {
  state.inspection = inspection;
  renderList(); // the limits column reads the inspection's
  if (state.selected) renderDetail();
  toleranceForm.open(inspection, state.me);
});

// ---- feedback ---------------------------------------------------------------------------

async function loadFeedback() {
  const out = await guarded(() => api.feedback(state.inspection.id));
  if (!out) return;
  const limit = (bound, value, unit) => `${bound === "min" ? "≥" : "≤"} ${value} ${unitText(unit)}`;
  $("#feedback-table tbody").replaceChildren(...out.groups.map((g) => el(
    "tr", { title: g.suggestion.reason },
    el("td", {}, g.type), el("td", {}, limit(g.bound, g.tolerance, g.unit)), el("td", {}, String(g.flagged)),
    el("td", {}, `${g.reviewed} (✓${g.confirmed} ✗${g.rejected})`), el("td", {}, String(g.missed)),
    el("td", {}, g.suggestion.action === "keep" ? "keep" : `${g.suggestion.action} to ${limit(g.bound, g.suggestion.tolerance, g.unit)}`),
  )));
  $("#suggested-tolerances").textContent = JSON.stringify(out.suggested_tolerances, null, 2);
}

// ---- tabs and routing ---------------------------------------------------------------------

for (const tab of document.querySelectorAll("[role=tab]")) {
  tab.addEventListener("click", () => {
    for (const other of document.querySelectorAll("[role=tab]")) {
      other.setAttribute("aria-selected", String(other === tab));
      $(`#tab-${other.dataset.tab}`).hidden = other !== tab;
    }
  });
}

async function route() {
  if (!session.token) {
    show("sign-in");
    $("#sign-out").hidden = true;
    $("#who").textContent = "";
    return;
  }
  if (!state.me) {
    state.me = await guarded(api.me);
    if (!state.me) return;
  }
  $("#who").textContent = `${state.me.username} (${state.me.role})`;
  document.body.classList.toggle("read-only", !canEdit(state.me)); // hides .editor-only
  $("#sign-out").hidden = false;
  if (state.stopJob) state.stopJob();
  state.stopJob = null;
  const job = /^#\/inspections\/(\d+)\/jobs\/(\d+)(?:\?points=(\d+))?$/.exec(location.hash);
  const match = /^#\/inspections\/(\d+)(?:\/defects\/(\d+))?$/.exec(location.hash);
  if (job) await showJobPage(Number(job[1]), Number(job[2]), job[3] ? Number(job[3]) : undefined);
  else if (match) await showInspection(Number(match[1]), match[2] ? Number(match[2]) : null);
  else {
    resetInspection();
    state.inspection = null;
    await showInspections();
  }
}

window.addEventListener("hashchange", route);
route();
