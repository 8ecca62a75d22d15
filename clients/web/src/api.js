// The supervisor's REST API (same origin): bearer token, problem-detail errors.
const API = "/api/v1";
const TOKEN_KEY = "vista.token";

export class ApiError extends Error {
  constructor(status, detail) {
    super(detail);
    this.status = status;
  }
}

export const session = {
  get token() { return sessionStorage.getItem(TOKEN_KEY); },
  set token(value) {
    if (value) sessionStorage.setItem(TOKEN_KEY, value);
    else sessionStorage.removeItem(TOKEN_KEY);
  },
};

async function failure(response) {
  let detail = response.statusText;
  try {
    const problem = await response.json();
    detail = problem.detail || problem.title || detail;
  } catch { /* not JSON: keep the status text */ }
  return new ApiError(response.status, detail);
}

export async function request(method, path, { body, params, headers, raw } = {}) {
  const url = new URL(API + path, location.origin);
  for (const [key, value] of Object.entries(params || {})) {
    if (value !== undefined && value !== null && value !== "") url.searchParams.set(key, value);
  }
  const init = { method, headers: { ...(headers || {}) } };
  if (session.token) init.headers.Authorization = `Bearer ${session.token}`;
  if (body !== undefined) {
    init.headers["Content-Type"] = "application/json";
    init.body = JSON.stringify(body);
  }
  const response = await fetch(url, init);
  if (!response.ok && response.status !== 304) throw await failure(response);
  return raw ? response : response.json();
}

export const api = {
  signIn: (username, password) => request("POST", "/auth/token", { body: { username, password } }),
  signOut: () => request("DELETE", "/auth/token", { raw: true }),
  me: () => request("GET", "/me"),
  inspections: () => request("GET", "/inspections", { params: { limit: 500 } }),
  inspection: (id) => request("GET", `/inspections/${id}`),
  runs: (id) => request("GET", `/inspections/${id}/runs`, { params: { limit: 100 } }),
  sync: (id, since) => request("GET", "/sync", { params: { inspection: id, since } }),
  judge: (defectId, body) => request("PUT", `/defects/${defectId}/judgments/me`, { body }),
  judgments: (defectId) => request("GET", `/defects/${defectId}/judgments`),
  defectHistory: (defectId) => request("GET", `/defects/${defectId}/history`),
  reportDefect: (body) => request("POST", "/defects", { body }),
  annotate: (defectId, text) => request("POST", `/defects/${defectId}/notes`, { body: { text } }),
  feedback: (id) => request("GET", "/feedback", { params: { inspection: id } }),
  jobView: (jobId) => request("GET", `/jobs/${jobId}/view`),
  jobScene: async (jobId, points) => (await request("GET", `/jobs/${jobId}/scene.glb`, { raw: true, params: { points } })).arrayBuffer(),
  artifactContent: async (id, artifactId) => (await request("GET", `/inspections/${id}/artifacts/${artifactId}/content`, { raw: true })).blob(),
  // Save an artifact's file as the user's download (the token cannot ride on a plain link).
  download: async (id, artifact) => {
    const blob = await api.artifactContent(id, artifact.id);
    const url = URL.createObjectURL(blob);
    const link = Object.assign(document.createElement("a"), { href: url, download: artifact.name });
    document.body.append(link);
    link.click();
    link.remove();
    setTimeout(() => URL.revokeObjectURL(url), 10_000);
  },
  createInspection: (body) => request("POST", "/inspections", { body }),
  areas: () => request("GET", "/areas"),
  updateInspection: (id, body) => request("PATCH", `/inspections/${id}`, { body }),
  toleranceSchema: () => request("GET", "/tolerances/schema"),
  toleranceSets: () => request("GET", "/tolerance-sets", { params: { limit: 500 } }),
  createToleranceSet: (body) => request("POST", "/tolerance-sets", { body }),
  applyToleranceSet: (id, setId) => request("POST", `/inspections/${id}/tolerance-set`, { body: { set_id: setId } }),
  artifactKinds: () => request("GET", "/artifact-kinds"),
  artifacts: (id) => request("GET", `/inspections/${id}/artifacts`, { params: { limit: 500 } }),
  jobKinds: () => request("GET", "/job-kinds"),
  createRun: (id, body) => request("POST", `/inspections/${id}/runs`, { body }),
  job: (jobId) => request("GET", `/jobs/${jobId}`),
  cancelJob: (jobId) => request("POST", `/jobs/${jobId}/cancel`),
  retryJob: (jobId) => request("POST", `/jobs/${jobId}/retry`),
  scene: (id, points, run) => request("GET", `/inspections/${id}/scene.glb`, { raw: true, params: { points, run } }),
  sceneRuns: (id) => request("GET", `/inspections/${id}/scene-runs`),
};

// Server-sent events of one job through fetch (EventSource cannot send the token).
export async function followJob(jobId, onEvent, signal) {
  const response = await fetch(`${API}/jobs/${jobId}/events`, {
    headers: { Authorization: `Bearer ${session.token}` },
    signal,
  });
  if (!response.ok) throw await failure(response);
  const reader = response.body.pipeThrough(new TextDecoderStream()).getReader();
  let buffer = "";
  for (;;) {
    const { value, done } = await reader.read();
    if (done) return;
    buffer += value;
    let cut;
    while ((cut = buffer.indexOf("\n\n")) >= 0) {
      const block = buffer.slice(0, cut);
      buffer = buffer.slice(cut + 2);
      const event = /^event: (.*)$/m.exec(block)?.[1];
      const data = /^data: (.*)$/m.exec(block)?.[1];
      if (event && data) onEvent(event, JSON.parse(data));
    }
  }
}

// An upload as the raw body, through XMLHttpRequest: fetch cannot report the bytes sent.
// onProgress(fraction) while it goes; resolves to the artifact kept, rejects with the
// server's sentence.
export function uploadArtifact(inspectionId, file, { kind, units }, onProgress) {
  const url = new URL(`${API}/inspections/${inspectionId}/artifacts`, location.origin);
  url.searchParams.set("kind", kind);
  url.searchParams.set("name", file.name);
  if (units) url.searchParams.set("units", units);
  return new Promise((resolve, reject) => {
    const xhr = new XMLHttpRequest();
    xhr.open("POST", url);
    xhr.setRequestHeader("Authorization", `Bearer ${session.token}`);
    xhr.setRequestHeader("Content-Type", file.type === "application/x-ply" ? file.type : "application/octet-stream");
    xhr.upload.onprogress = (event) => { if (event.lengthComputable) onProgress(event.loaded / event.total); };
    xhr.onload = () => {
      let body = null;
      try { body = JSON.parse(xhr.responseText); } catch { /* not JSON */ }
      if (xhr.status >= 200 && xhr.status < 300) resolve(body);
      else reject(new ApiError(xhr.status, body?.detail || body?.title || xhr.statusText));
    };
    xhr.onerror = () => reject(new ApiError(0, "the upload was cut off: the server could not be reached"));
    xhr.send(file);
  });
}
