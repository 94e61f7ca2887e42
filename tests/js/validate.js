// The Khronos glTF validator (npm gltf-validator, pinned in package.json) for farfield's tests.
//
// One process validates many files: it reads JSON lines from stdin, each {"paths": [...]}, and
// answers each with one JSON line {"results": [...]}, one entry per path, in order:
//   {"path", "errors", "warnings", "infos", "hints", "messages": [{"code", "severity", "message", "pointer"}]}
// (severity 0 error, 1 warning, 2 info, 3 hint: the validator's own numbering) or {"path", "failed": text}
// when the validator refused the bytes outright.  With paths as arguments it validates those and exits.
// External resources (a .gltf's buffers and images) are read beside the file.
"use strict";
const fs = require("fs");
const path = require("path");
const readline = require("readline");
const validator = require("gltf-validator");

async function validate(file) {
  try {
    const data = fs.readFileSync(file);
    const report = await validator.validateBytes(new Uint8Array(data), {
      uri: path.basename(file),
      maxIssues: 100,
      externalResourceFunction: (uri) =>
        new Promise((resolve, reject) => {
          fs.readFile(path.resolve(path.dirname(file), decodeURIComponent(uri)), (error, bytes) =>
            error ? reject(error.toString()) : resolve(new Uint8Array(bytes)));
        }),
    });
    const issues = report.issues;
    return {
      path: file,
      errors: issues.numErrors,
      warnings: issues.numWarnings,
      infos: issues.numInfos,
      hints: issues.numHints,
      messages: issues.messages.map((m) => ({ code: m.code, severity: m.severity, message: m.message, pointer: m.pointer })),
    };
  } catch (error) {
    return { path: file, failed: String(error) };
  }
}

async function validateAll(paths) {
  const results = [];
  for (const file of paths) results.push(await validate(file));  // in order, one at a time
  return results;
}

async function main() {
  const args = process.argv.slice(2);
  if (args.length) {
    process.stdout.write(JSON.stringify({ version: validator.version(), results: await validateAll(args) }) + "\n");
    return;
  }
  process.stdout.write(JSON.stringify({ version: validator.version() }) + "\n");  // ready
  const lines = readline.createInterface({ input: process.stdin, crlfDelay: Infinity });
  for await (const line of lines) {
    if (!line.trim()) continue;
    const request = JSON.parse(line);
    process.stdout.write(JSON.stringify({ results: await validateAll(request.paths) }) + "\n");
  }
}

main();
