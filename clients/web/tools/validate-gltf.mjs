// Validate glTF/GLB files with the Khronos glTF-Validator; prints one JSON report per file
// (its issues summary and messages) and exits 1 if any file has errors.
//   node tools/validate-gltf.mjs scene.glb [more.glb …]
import { readFile } from "node:fs/promises";
import validator from "gltf-validator";

const files = process.argv.slice(2);
if (files.length === 0) {
  console.error("usage: node tools/validate-gltf.mjs FILE.glb [FILE.glb …]");
  process.exit(2);
}
let failed = false;
const reports = [];
for (const file of files) {
  const bytes = new Uint8Array(await readFile(file));
  const report = await validator.validateBytes(bytes, { maxIssues: 200, uri: file });
  failed ||= report.issues.numErrors > 0;
  reports.push({
    file,
    validatorVersion: report.validatorVersion,
    issues: report.issues,
    info: report.info,
  });
}
console.log(JSON.stringify(reports));
process.exit(failed ? 1 : 0);
