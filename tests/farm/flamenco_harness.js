// A small stand-in for Flamenco 3's job compiler, to run a job type under Node:
//
//   node flamenco_harness.js JOB_TYPE.js SETTINGS.json
//
// loads the job type as the Manager does (a script with JOB_TYPE and compileJob in one scope, and the
// globals `author`, `frameChunker`, `path`, `print`, `formatTimestampLocal`), compiles a job with the given
// settings and prints {"job_type": JOB_TYPE, "tasks": [...]} as JSON: each task's name, type, commands
// (name, parameters, total frames) and the names of the tasks it depends on.
"use strict";
const fs = require("fs");
const nodePath = require("path").posix;
const vm = require("vm");

function frameChunker(frames, chunkSize) {
  // Flamenco's contract: "1-30, 40" -> contiguous chunks of at most chunkSize frames, "a-b" or "a".
  const list = [];
  for (const part of String(frames).split(",")) {
    const text = part.trim();
    if (!text) continue;
    const bounds = text.split("-").map((v) => parseInt(v, 10));
    if (bounds.some(Number.isNaN)) throw `bad frame range ${text}`;
    for (let f = bounds[0]; f <= (bounds.length > 1 ? bounds[1] : bounds[0]); f++) list.push(f);
  }
  const sorted = [...new Set(list)].sort((a, b) => a - b);
  const chunks = [];
  let start = 0;
  while (start < sorted.length) {
    let end = start;
    while (end + 1 < sorted.length && end + 1 - start < chunkSize && sorted[end + 1] === sorted[end] + 1) end++;
    chunks.push(sorted[start] === sorted[end] ? `${sorted[start]}` : `${sorted[start]}-${sorted[end]}`);
    start = end + 1;
  }
  return chunks;
}

class Task {
  constructor(name, type) {
    this.name = name;
    this.type = type;
    this.commands = [];
    this.dependencies = [];
  }
  addCommand(command) { this.commands.push(command); }
  addDependency(task) {
    if (!(task instanceof Task)) throw "addDependency takes a task";
    this.dependencies.push(task.name);
  }
}

const author = {
  Task: (name, type) => new Task(name, type),
  Command: (name, parameters, totalFrames) => ({ name, parameters, totalFrames }),
};

const [jobTypePath, settingsPath] = process.argv.slice(2);
const settings = JSON.parse(fs.readFileSync(settingsPath, "utf8"));
const tasks = [];
const job = {
  settings,
  created: new Date(Date.UTC(2026, 11, 6, 3, 4, 5)),
  addTask(task) {
    if (!(task instanceof Task)) throw "addTask takes a task";
    tasks.push(task);
  },
};
const context = vm.createContext({
  author,
  frameChunker,
  path: { join: nodePath.join, dirname: nodePath.dirname, basename: nodePath.basename,
          stem: (p) => nodePath.basename(p, nodePath.extname(p)) },
  print: (...args) => process.stderr.write(args.map(String).join(" ") + "\n"),
  formatTimestampLocal: (date) => date.toISOString().slice(0, 19).replace(/[-:]/g, "").replace("T", "-"),
});
vm.runInContext(fs.readFileSync(jobTypePath, "utf8") + "\n;globalThis.__jobType = JOB_TYPE;", context,
                { filename: jobTypePath });
try {
  context.compileJob(job);
} catch (error) {
  process.stdout.write(JSON.stringify({ error: String(error) }) + "\n");
  process.exit(3);
}
process.stdout.write(JSON.stringify({ job_type: context.__jobType, tasks }) + "\n");
