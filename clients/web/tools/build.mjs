// Build the dashboard into dist/: one bundled, minified script (three.js included), the
// page and its style sheet. `npm run build`; the supervisor serves dist/ at `/`.
import { build } from "esbuild";
import { copyFile, mkdir, rm } from "node:fs/promises";

const out = new URL("../dist/", import.meta.url);
const src = new URL("../src/", import.meta.url);
await rm(out, { recursive: true, force: true });
await mkdir(out, { recursive: true });
await build({
  entryPoints: [new URL("main.js", src).pathname],
  bundle: true,
  minify: true,
  sourcemap: true,
  format: "esm",
  target: ["chrome110", "firefox115", "safari16"],
  outfile: new URL("app.js", out).pathname,
  logLevel: "warning",
});
for (const file of ["index.html", "style.css", "favicon.svg"]) {
  await copyFile(new URL(file, src), new URL(file, out));
}
console.log(`dashboard built in ${out.pathname}`);
