// Build the editor's bundle into the server's static folder, with the licences of every
// package inside it. Run by a maintainer after changing package.json (see README.md); the
// output is committed, so neither users nor CI ever run npm.
import { build } from "esbuild";
import { createHash } from "node:crypto";
import { readFileSync, writeFileSync } from "node:fs";
import { dirname, join } from "node:path";
import { fileURLToPath } from "node:url";

const here = dirname(fileURLToPath(import.meta.url));
const stat = join(here, "..", "..", "src", "opendnc", "server", "web", "static");
const view = JSON.parse(readFileSync(join(here, "node_modules/@codemirror/view/package.json"), "utf8"));
const name = `codemirror-${view.version}.min.js`;

const result = await build({
  entryPoints: [join(here, "entry.js")],
  bundle: true,
  minify: true,
  format: "iife",
  globalName: "CM",
  target: ["es2020"],
  legalComments: "none",
  metafile: true,
  outfile: join(stat, name),
});

// the packages whose code is in the bundle, each with its licence text
const packages = new Set();
for (const input of Object.keys(result.metafile.inputs)) {
  const m = /node_modules\/((?:@[^/]+\/)?[^/]+)\//.exec(input);
  if (m) packages.add(m[1]);
}
let licences = `Licences of the packages bundled in ${name} (built by tools/editor-bundle).\n`;
for (const pkg of [...packages].sort()) {
  const dir = join(here, "node_modules", pkg);
  const meta = JSON.parse(readFileSync(join(dir, "package.json"), "utf8"));
  licences += `\n==== ${pkg}@${meta.version} (${meta.license}) ====\n\n`;
  licences += readFileSync(join(dir, "LICENSE"), "utf8").trim() + "\n";
}
writeFileSync(join(stat, "LICENSE.codemirror"), licences);
const digest = createHash("sha256").update(readFileSync(join(stat, name))).digest("hex");
console.log(`${name} sha256 ${digest}`);
console.log(`packages: ${[...packages].sort().join(", ")}`);
