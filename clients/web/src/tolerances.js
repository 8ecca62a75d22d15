// An inspection's tolerances in the browser: a form drawn from the tolerance document's
// JSON Schema (GET /tolerances/schema) with every default shown, saved as a PATCH that
// names only the limits changed (an emptied limit goes back to its default); named
// tolerance sets applied to the inspection or made from its limits.
import { api } from "./api.js";
import { el } from "./dom.js";

const $ = (selector) => document.querySelector(selector);
const LABELS = {
  gap_mm: "gap", step_mm: "step", parallelism_mm: "parallelism", mismatch_mm: "mismatch", surface: "surface",
  min: "minimum", max: "maximum", dent_depth_mm: "dent depth (and bump height)",
  scratch_depth_mm: "scratch depth", color_delta_e: "colour difference",
};

// A schema's object behind a property (its $ref, or the one branch of anyOf that is not null).
function resolve(schema, property) {
  const branch = (property.anyOf || [property]).find((p) => p.type !== "null") || property;
  return branch.$ref ? schema.$defs[branch.$ref.split("/").pop()] : branch;
}

// Every limit the document has: [section, key, its number schema], in the schema's order.
function fieldsOf(schema) {
  return Object.entries(schema.properties).flatMap(([section, property]) =>
    Object.entries(resolve(schema, property).properties).map(([key, limit]) => [section, key, resolve(schema, limit)]));
}

export class ToleranceForm {
  constructor(onSaved) {
    this.onSaved = onSaved; // (inspection) → void: the page redraws with the new limits
    this.schema = null;
    this.inspection = null;
    $("#tolerance-form").addEventListener("submit", (event) => { event.preventDefault(); this.save(); });
    $("#apply-set").addEventListener("click", () => this.applySet());
    $("#save-set").addEventListener("click", () => this.saveAsSet());
  }

  async open(inspection, me) {
    this.inspection = inspection;
    this.schema ||= await api.toleranceSchema();
    const mine = me.role === "admin" || inspection.created_by === me.id;
    const own = inspection.tolerances || {};
    const { defaults } = this.schema;
    const unit = (key) => (key === "color_delta_e" ? "ΔE" : "mm");
    $("#tolerance-fields").replaceChildren(...fieldsOf(this.schema.schema).map(([section, key, limit]) => {
      const value = own[section]?.[key];
      const fallback = defaults[section]?.[key];
      const bound = limit.exclusiveMinimum ?? limit.minimum;
      return el("label", { class: "tolerance-field", dataset: { section, key }, title: `default ${fallback} ${unit(key)}${limit.description ? ` · ${limit.description}` : ""}` },
        el("span", {}, `${LABELS[section] || section} ${LABELS[key] || key}`),
        el("input", {
          type: "number", step: "any", name: `${section}.${key}`, value: value ?? "",
          placeholder: `default ${fallback}`, ...(bound !== undefined ? { min: String(bound) } : {}),
          ...(limit.maximum !== undefined ? { max: String(limit.maximum) } : {}),
          ...(mine ? {} : { disabled: "" }), "aria-label": `${section} ${key}`,
        }),
        el("span", { class: "muted" }, unit(key)));
    }));
    $("#tolerance-save").disabled = !mine;
    $("#apply-set").disabled = !mine;
    $("#tolerance-owner").hidden = mine;
    const applied = inspection.tolerance_set;
    $("#tolerance-applied").textContent = applied
      ? `From the set “${applied.name}” version ${applied.version}${applied.edited ? ", edited here since" : ""}.`
      : "Limits of this inspection's own (no set applied).";
    $("#tolerance-error").textContent = "";
    await this.loadSets();
  }

  async loadSets() {
    const sets = (await api.toleranceSets()).items;
    const chosen = $("#tolerance-sets").value; // a choice made meanwhile stays
    $("#tolerance-sets").replaceChildren(
      el("option", { value: "" }, sets.length ? "choose a set" : "no sets yet"),
      ...sets.map((s) => el("option", { value: String(s.id) }, `${s.name} (version ${s.version})`)),
    );
    if (sets.some((s) => String(s.id) === chosen)) $("#tolerance-sets").value = chosen;
  }

  // Only what changed: a new value, or null where a limit of its own was emptied.
  changes() {
    const own = this.inspection.tolerances || {};
    const patch = {};
    for (const input of document.querySelectorAll("#tolerance-fields input")) {
      const [section, key] = input.name.split(".");
      const before = own[section]?.[key] ?? null;
      const after = input.value.trim() === "" ? null : Number(input.value);
      if (after !== before) (patch[section] ||= {})[key] = after;
    }
    return patch;
  }

  async run(action, said) {
    $("#tolerance-error").textContent = "";
    $("#tolerance-status").textContent = "saving…";
    try {
      const inspection = await action();
      if (inspection) {
        this.onSaved(inspection);
        $("#tolerance-status").textContent = said;
      }
    } catch (error) {
      $("#tolerance-error").textContent = error.message;
    }
  }

  save() {
    const patch = this.changes();
    if (!Object.keys(patch).length) {
      $("#tolerance-status").textContent = "Nothing changed.";
      return Promise.resolve();
    }
    return this.run(() => api.updateInspection(this.inspection.id, { tolerances: patch }), "Saved; the findings are judged again by the new limits.");
  }

  applySet() {
    const id = Number($("#tolerance-sets").value);
    if (!id) {
      $("#tolerance-error").textContent = "Choose a set to apply.";
      return Promise.resolve();
    }
    return this.run(() => api.applyToleranceSet(this.inspection.id, id), "Applied; the findings are judged again by its limits.");
  }

  saveAsSet() {
    const name = $("#set-name").value.trim();
    if (!name) {
      $("#tolerance-error").textContent = "Name the set first.";
      return Promise.resolve();
    }
    return this.run(async () => {
      await api.createToleranceSet({ name, tolerances: this.inspection.tolerances || {} });
      $("#set-name").value = "";
      await this.loadSets();
      return null;
    }, "").then(() => { if (!$("#tolerance-error").textContent) $("#tolerance-status").textContent = `Saved as the set “${name}”.`; });
  }
}
