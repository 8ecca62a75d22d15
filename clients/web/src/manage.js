// Doing the job from the browser: create an inspection, upload its files with progress,
// start a run from the job kinds' own declarations (their inputs and the JSON schema of
// their parameters, GET /job-kinds), and cancel or retry a job. Nothing here names a
// service: a new job kind's form draws the same way.
import { api, uploadArtifact } from "./api.js";
import { el, sizeText } from "./dom.js";

const $ = (selector) => document.querySelector(selector);
// Suggestions only: an inspection's area is free text (the API's own list, GET /areas,
// adds the areas earlier inspections used).
const AREAS = ["cabin", "cargo", "component"];
const UNITS = [["", "the format's own"], ["mm", "mm"], ["cm", "cm"], ["m", "m"], ["in", "in"], ["ft", "ft"]];
export const FINISHED = ["succeeded", "failed", "cancelled"];

export const canEdit = (me) => ["admin", "inspector"].includes(me?.role);

// ---- a new inspection ---------------------------------------------------------------------

export function setUpNewInspection() {
  const suggest = (areas) => $("#area-suggestions").replaceChildren(...areas.map((a) => el("option", { value: a })));
  suggest(AREAS);
  $("#new-inspection-area").addEventListener("focus", () => {
    api.areas().then(suggest).catch(() => {}); // signed out: the built-in suggestions stay
  });
  $("#new-inspection-form").addEventListener("submit", async (event) => {
    event.preventDefault();
    const form = new FormData(event.target);
    $("#new-inspection-error").textContent = "";
    try {
      const created = await api.createInspection({
        title: form.get("title"), aircraft: form.get("aircraft"), area: form.get("area"),
      });
      event.target.reset();
      location.hash = `#/inspections/${created.id}`;
    } catch (error) {
      $("#new-inspection-error").textContent = error.message;
    }
  });
}

// ---- files --------------------------------------------------------------------------------

export class Files {
  constructor(onUploaded) {
    this.inspectionId = null;
    this.items = [];
    this.onUploaded = onUploaded;
    $("#upload-units").replaceChildren(...UNITS.map(([v, t]) => el("option", { value: v }, t)));
    $("#upload-form").addEventListener("submit", (event) => {
      event.preventDefault();
      this.uploadChosen();
    });
  }

  async open(inspectionId) {
    this.inspectionId = inspectionId;
    if (!$("#upload-kind").options.length) {
      const kinds = await api.artifactKinds();
      $("#upload-kind").replaceChildren(...kinds.map((k) => el("option", { value: k.name, title: k.description }, k.name)));
      $("#upload-kind").value = "cloud";
    }
    await this.reload();
  }

  async reload() {
    const id = this.inspectionId;
    const page = await api.artifacts(id);
    if (id !== this.inspectionId) return;
    this.items = page.items;
    $("#artifact-table tbody").replaceChildren(...page.items.map((a) => el(
      "tr", { dataset: { id: a.id } },
      el("td", {}, el("button", { class: "link", title: "download", dataset: { download: a.id }, onclick: () => api.download(id, a) }, a.name)),
      el("td", {}, a.kind), el("td", {}, sizeText(a.size_bytes)),
      el("td", {}, whenText(a.created_at)),
      el("td", {}, madeBy(a, id)),
      el("td", {}, sourceText(a)),
    )));
    $("#files-empty").hidden = page.items.length > 0;
  }

  // Each chosen file goes up on its own with a bar; a refusal stays beside its name.
  async uploadChosen() {
    const files = [...$("#upload-file").files];
    if (!files.length) {
      $("#upload-error").textContent = "Choose a file first.";
      return;
    }
    $("#upload-error").textContent = "";
    const kind = $("#upload-kind").value;
    const units = $("#upload-units").value;
    for (const file of files) {
      const bar = el("progress", { max: "1", value: "0" });
      const status = el("span", { class: "muted" }, "uploading…");
      const line = el("li", { dataset: { name: file.name } }, el("b", {}, file.name), ` ${sizeText(file.size)} `, bar, status);
      $("#uploads").prepend(line);
      try {
        const kept = await uploadArtifact(this.inspectionId, file, { kind, units }, (f) => { bar.value = f; });
        bar.value = 1;
        status.textContent = `kept as ${kept.name} (${kept.kind}${kept.meta?.source ? `, from ${sourceText(kept)}` : ""})`;
        line.classList.add("done");
      } catch (error) {
        status.textContent = error.message;
        status.className = "error";
        line.classList.add("refused");
      }
    }
    $("#upload-form").reset();
    $("#upload-kind").value = kind;
    await this.reload();
    this.onUploaded();
  }
}

function whenText(iso) {
  return new Date(iso).toLocaleString([], { dateStyle: "short", timeStyle: "short" });
}

// Who uploaded a file, or the run and step whose job made it (a link to the job's page).
function madeBy(artifact, inspectionId) {
  if (artifact.job_id === null) return `uploaded by ${artifact.created_by_name || "someone removed"}`;
  return el("a", { href: `#/inspections/${inspectionId}/jobs/${artifact.job_id}` }, `run ${artifact.run_id}, step ${artifact.step}`);
}

// A file as a picker lists it: name, kind, size, when, and where it came from.
function fileLabel(artifact) {
  const from = artifact.job_id === null ? "uploaded" : `run ${artifact.run_id} ${artifact.step}`;
  return `${artifact.name} · ${artifact.kind} · ${sizeText(artifact.size_bytes)} · ${whenText(artifact.created_at)} · ${from} (#${artifact.id})`;
}

function sourceText(artifact) {
  const source = artifact.meta?.source;
  if (!source) return "";
  return `${source.format_name} in ${source.units}${source.units_assumed ? " (its convention)" : ""}`;
}

// ---- a run from a job kind's declaration --------------------------------------------------

export class RunForm {
  constructor(files, onStarted) {
    this.files = files;
    this.kinds = [];
    this.onStarted = onStarted;
    $("#run-kind").addEventListener("change", () => this.drawKind());
    $("#run-form").addEventListener("submit", (event) => {
      event.preventDefault();
      this.start();
    });
  }

  async open(inspectionId) {
    this.inspectionId = inspectionId;
    if (!this.kinds.length) {
      this.kinds = await api.jobKinds();
      $("#run-kind").replaceChildren(...this.kinds.map((k) => el("option", { value: k.name, title: k.description }, k.name)));
      $("#run-kind").value = this.kinds.some((k) => k.name === "defects.measure") ? "defects.measure" : this.kinds[0]?.name;
    }
    await this.files.open(inspectionId);
    this.drawKind();
  }

  get kind() {
    return this.kinds.find((k) => k.name === $("#run-kind").value);
  }

  // The kind's inputs as pickers of this inspection's files of the kinds it reads, and
  // its parameters as fields from their JSON schema (defaults shown, nothing sent unless
  // changed).
  drawKind() {
    const kind = this.kind;
    if (!kind) return;
    $("#run-error").textContent = "";
    $("#run-description").replaceChildren(...withCode(kind.description));
    $("#run-inputs").replaceChildren(...kind.inputs.map((spec, index) => inputPicker(spec, index, this.files.items)));
    const schema = kind.params_schema;
    $("#run-params").replaceChildren(...Object.entries(schema.properties || {}).map(([name, property]) => paramField(name, property, schema)));
  }

  async start() {
    const kind = this.kind;
    $("#run-error").textContent = "";
    let params;
    try {
      params = readParams(kind.params_schema);
    } catch (error) {
      $("#run-error").textContent = error.message;
      return;
    }
    const inputs = [...document.querySelectorAll("#run-inputs [data-input]")].flatMap((node) => (
      node.tagName === "SELECT" ? (node.value ? [Number(node.value)] : []) : (node.checked ? [Number(node.value)] : [])
    ));
    const step = { name: kind.name.split(".").pop(), kind: kind.name, inputs, params };
    const name = $("#run-name").value.trim();
    try {
      const run = await api.createRun(this.inspectionId, { ...(name ? { name } : {}), steps: [step] });
      $("#run-name").value = "";
      this.onStarted(run);
    } catch (error) {
      $("#run-error").textContent = error.message;
    }
  }
}

// A kind's description as written for the API's documentation: `code` drawn as code.
function withCode(text) {
  return text.split("`").map((part, i) => (i % 2 ? el("code", {}, part) : part));
}

function inputPicker(spec, index, artifacts) {
  const fits = artifacts.filter((a) => spec.kinds.includes("*") || spec.kinds.includes(a.kind));
  const count = spec.max === null ? `${spec.min} or more` : spec.min === spec.max ? `${spec.min}` : `${spec.min}–${spec.max}`;
  const legend = el("legend", {}, `${spec.what} — ${count} of: ${spec.kinds.join(", ")}`);
  if (!fits.length) {
    const none = spec.min ? "none of this inspection's files fits: upload one in the Files tab" : "none (optional)";
    return el("fieldset", { class: "run-input" }, legend, el("p", { class: "muted" }, none));
  }
  if (spec.max === 1) {
    const select = el("select", { "data-input": String(index), "aria-label": spec.what },
      ...(spec.min ? [] : [el("option", { value: "" }, "none")]),
      ...fits.slice().reverse().map((a) => el("option", { value: String(a.id) }, fileLabel(a))));
    return el("fieldset", { class: "run-input" }, legend, select);
  }
  // Several: a list filtered by kind, each file on its own line, and "all of a kind".
  const kinds = [...new Set(fits.map((a) => a.kind))];
  const rows = fits.map((a) => el(
    "label", { class: "pick", title: fileLabel(a), dataset: { kind: a.kind } },
    el("input", { type: "checkbox", value: String(a.id), "data-input": String(index) }), ` ${fileLabel(a)}`,
  ));
  const shown = () => rows.filter((r) => !r.hidden);
  const filter = el("select", {
    "aria-label": `${spec.what}: kind shown`, class: "pick-kind",
    onchange: () => { for (const row of rows) row.hidden = Boolean(filter.value) && row.dataset.kind !== filter.value; },
  }, el("option", { value: "" }, "every kind"), ...kinds.map((k) => el("option", { value: k }, k)));
  const all = el("button", {
    type: "button", class: "pick-all",
    onclick: () => { for (const row of shown()) row.querySelector("input").checked = true; },
  }, "select all shown");
  const clear = el("button", {
    type: "button", class: "pick-none",
    onclick: () => { for (const row of shown()) row.querySelector("input").checked = false; },
  }, "clear");
  return el("fieldset", { class: "run-input" }, legend, el("div", { class: "pick-tools" }, filter, all, clear), el("div", { class: "pick-list" }, ...rows));
}

// A property's own schema: an optional value's non-null branch, a reference resolved.
function resolved(property, schema) {
  let own = property;
  if (own.anyOf) own = { ...own, ...own.anyOf.find((branch) => branch.type !== "null") };
  if (own.$ref) own = { ...own, ...schema.$defs?.[own.$ref.split("/").pop()] };
  return own;
}

function paramField(name, property, schema) {
  const own = resolved(property, schema);
  const title = own.description || property.description || "";
  const label = (field) => el("label", { class: "param", title }, el("span", {}, name), field, el("small", { class: "muted" }, title));
  const data = { "data-param": name };
  if (own.enum) {
    const select = el("select", data, ...own.enum.map((v) => el("option", { value: String(v) }, String(v))));
    if (property.default !== undefined) select.value = String(property.default);
    return label(select);
  }
  if (own.type === "boolean") {
    const box = el("input", { type: "checkbox", ...data });
    box.checked = Boolean(property.default);
    return label(box);
  }
  if (own.type === "number" || own.type === "integer") {
    const attributes = { type: "number", step: own.type === "integer" ? "1" : "any", ...data };
    for (const [bound, key] of [["minimum", "min"], ["maximum", "max"]]) if (own[bound] !== undefined) attributes[key] = String(own[bound]);
    if (property.default !== undefined && property.default !== null) attributes.placeholder = String(property.default);
    return label(el("input", attributes));
  }
  if (own.type === "string") {
    return label(el("input", { type: "text", placeholder: property.default ?? "", ...data }));
  }
  // a list of numbers: the numbers as its description gives them, spaces or commas between
  if (own.type === "array" && ["number", "integer"].includes(resolved(own.items || {}, schema).type)) {
    const size = own.minItems === own.maxItems && own.minItems ? `${own.minItems} numbers` : "numbers";
    return label(el("input", { type: "text", placeholder: `${size}, spaces between`, "data-numbers": "1", ...data }));
  }
  // objects and other lists: JSON, as the API takes them
  return label(el("textarea", { rows: "2", placeholder: property.default === undefined ? "JSON" : JSON.stringify(property.default), "data-json": "1", ...data }));
}

function readParams(schema) {
  const params = {};
  for (const node of document.querySelectorAll("#run-params [data-param]")) {
    const name = node.dataset.param;
    const property = schema.properties[name];
    if (node.type === "checkbox") {
      if (node.checked !== Boolean(property.default)) params[name] = node.checked;
    } else if (node.dataset.numbers) {
      const text = node.value.trim().replace(/^\[|\]$/g, "");
      if (text) {
        const numbers = text.split(/[\s,]+/).map(Number);
        if (numbers.some((n) => !Number.isFinite(n))) throw new Error(`${name}: numbers separated by spaces (e.g. 1.5 1.6 3.9 2.1 1.7 8.4 -1.56)`);
        params[name] = numbers;
      }
    } else if (node.dataset.json) {
      if (node.value.trim()) {
        try { params[name] = JSON.parse(node.value); } catch { throw new Error(`${name}: not valid JSON`); }
      }
    } else if (node.value !== "" && node.value !== String(property.default ?? "")) {
      params[name] = node.type === "number" ? Number(node.value) : node.value;
    }
  }
  return params;
}

// ---- a job's cancel and retry ---------------------------------------------------------------

// The buttons a job row offers: cancel while it waits or runs, retry once it failed or was
// cancelled. onDone() redraws the runs.
export function jobButtons(job, me, onDone, onError) {
  if (!canEdit(me)) return [];
  const act = (label, action) => el("button", {
    class: "job-action", "data-action": label.toLowerCase(),
    onclick: async (event) => {
      event.currentTarget.disabled = true;
      try { await action(job.id); onDone(); } catch (error) { onError(error); }
    },
  }, label);
  if (!FINISHED.includes(job.status)) return [act("Cancel", api.cancelJob)];
  if (job.status === "failed" || job.status === "cancelled") return [act("Retry", api.retryJob)];
  return [];
}
