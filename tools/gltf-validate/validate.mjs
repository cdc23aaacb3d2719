#!/usr/bin/env node
// Runs the Khronos glTF validator over GLB/glTF files.
//
// Usage: node validate.mjs [--verbose] PATH...   (files, or directories
// searched recursively for *.glb; --verbose also lists infos and hints)
//
// Prints one line per file — error/warning/info/hint counts and the first few
// error messages — and exits 1 when any file has an error (2 on bad usage or
// when no file was found), so CI can gate on it. The validator reports
// EXT_meshopt_compression as unsupported: validate the uncompressed variant.
import fs from 'node:fs';
import path from 'node:path';
import { validateBytes } from 'gltf-validator';

const SHOWN = 5;

function collect(p, out) {
  const stat = fs.statSync(p);
  if (stat.isDirectory()) {
    for (const name of fs.readdirSync(p).sort()) {
      const child = path.join(p, name);
      if (fs.statSync(child).isDirectory() || name.toLowerCase().endsWith('.glb')) {
        collect(child, out);
      }
    }
  } else {
    out.push(p);
  }
}

function format(message) {
  return `${message.code} at ${message.pointer ?? '?'}: ${message.message}`;
}

async function validate(file) {
  const dir = path.dirname(file);
  const report = await validateBytes(new Uint8Array(fs.readFileSync(file)), {
    maxIssues: 50,
    uri: path.basename(file),
    // Only for .gltf files with external buffers or images next to them.
    externalResourceFunction: (uri) =>
      new Promise((resolve, reject) => {
        fs.readFile(path.join(dir, decodeURIComponent(uri)), (err, data) =>
          err ? reject(err.toString()) : resolve(new Uint8Array(data)),
        );
      }),
  });
  const i = report.issues;
  let line = `${file}: ${i.numErrors} errors, ${i.numWarnings} warnings, ${i.numInfos} infos, ${i.numHints} hints`;
  const errors = i.messages.filter((m) => m.severity === 0).slice(0, SHOWN);
  const warnings = i.messages.filter((m) => m.severity === 1).slice(0, SHOWN);
  for (const m of errors) line += `\n  error: ${format(m)}`;
  for (const m of warnings) line += `\n  warning: ${format(m)}`;
  if (verbose) {
    for (const m of i.messages.filter((m) => m.severity >= 2)) {
      line += `\n  ${m.severity === 2 ? 'info' : 'hint'}: ${format(m)}`;
    }
  }
  console.log(line);
  return i.numErrors;
}

const verbose = process.argv.includes('--verbose') || process.argv.includes('-v');
const args = process.argv.slice(2).filter((a) => a !== '--verbose' && a !== '-v');
if (args.length === 0) {
  console.error('usage: node validate.mjs [--verbose] FILE_OR_DIR...');
  process.exit(2);
}
const files = [];
for (const a of args) {
  if (!fs.existsSync(a)) {
    console.error(`${a}: no such file or directory`);
    process.exit(2);
  }
  collect(a, files);
}
if (files.length === 0) {
  console.error('no .glb files found');
  process.exit(2);
}
let failed = 0;
for (const f of files) {
  try {
    if ((await validate(f)) > 0) failed += 1;
  } catch (e) {
    console.log(`${f}: validator failed: ${e}`);
    failed += 1;
  }
}
console.log(`gltf-validate: ${files.length} files, ${failed} with errors`);
process.exit(failed > 0 ? 1 : 0);
