// SPDX-License-Identifier: GPL-3.0-or-later
//
// LazyVis Tiled: a Flamenco 3 job type that renders frames with the LazyVis engine as a grid of render
// borders (tiles) on the workers, then stitches each frame's tiles with `lazyvis merge`.
//
// Install: copy this file into the Manager's `scripts/` folder (beside flamenco-manager) and restart the
// Manager; Blender's Flamenco add-on then offers "LazyVis Tiled" under Output Properties > Flamenco.
// Workers need Blender with the LazyVis extension enabled (for `-E LAZYVIS` and the operator
// `bpy.ops.lazyvis.set_tile`), and the `lazyvis` command for the merge task (`pip install lazyvis`, or
// the path to it in the `lazyvis_cmd` setting).
//
// A tile is pixel for pixel the full frame's there (LazyVis renders the margin its anti-aliasing reads),
// so the merged frame equals a render of the whole frame.

const JOB_TYPE = {
  label: "LazyVis Tiled",
  description: "Render with LazyVis as tiles on several workers, then merge each frame's tiles",
  settings: [
    // Settings for artists to determine:
    {
      key: "frames",
      type: "string",
      required: true,
      eval: "f'{C.scene.frame_start}-{C.scene.frame_end}'",
      evalInfo: { showLinkButton: true, description: "Scene frame range" },
      description: "Frame range to render. Examples: '47', '1-30', '3, 5-10, 47-327'",
    },
    {
      key: "chunk_size",
      type: "int32",
      default: 1,
      description: "Frames per render task (each task renders one tile of these frames)",
      visible: "submission",
    },
    { key: "tiles_x", type: "int32", default: 2, description: "Tile columns (1 to 64)", visible: "submission" },
    { key: "tiles_y", type: "int32", default: 2, description: "Tile rows (1 to 64)", visible: "submission" },
    {
      key: "multilayer",
      type: "bool",
      default: true,
      description: "Every pass in a multilayer EXR (off: RGBA only)",
      visible: "submission",
    },
    // render_output_root + add_path_components determine render_output_path, as in Flamenco's own types.
    {
      key: "render_output_root",
      type: "string",
      subtype: "dir_path",
      required: true,
      visible: "submission",
      description: "Base directory of where render output is stored. Will have some job-specific parts appended to it",
    },
    {
      key: "add_path_components",
      type: "int32",
      required: true,
      default: 0,
      propargs: { min: 0, max: 32 },
      visible: "submission",
      description: "Number of path components of the current blend file to use in the render output path",
    },
    {
      key: "render_output_path",
      type: "string",
      subtype: "file_path",
      editable: false,
      eval: "str(Path(abspath(settings.render_output_root), last_n_dir_parts(settings.add_path_components), jobname, '{timestamp}', '######'))",
      description: "Final file path of where render output will be saved",
    },
    {
      key: "lazyvis_cmd",
      type: "string",
      default: "lazyvis",
      visible: "submission",
      description: "The lazyvis command on the workers, which merges the tiles",
    },
    // Automatically evaluated settings:
    { key: "blendfile", type: "string", required: true, visible: "web", description: "Path of the Blend file to render" },
    { key: "scene", type: "string", eval: "C.scene.name", visible: "web", description: "Name of the scene to render" },
  ],
};

function compileJob(job) {
  print("LazyVis tiled render job submitted");
  const settings = job.settings;
  const columns = checkedCount(settings.tiles_x, "tiles_x");
  const rows = checkedCount(settings.tiles_y, "tiles_y");
  const renderOutput = renderOutputPath(job);
  const renderDir = path.dirname(renderOutput);
  const tileDir = path.join(renderDir, "tiles");

  for (const chunk of frameChunker(settings.frames, settings.chunk_size || 1)) {
    const tileTasks = [];
    for (let tile = 0; tile < columns * rows; tile++) {
      const task = author.Task(`render-${chunk}-tile-${tile}`, "blender");
      task.addCommand(author.Command(
        "blender-render",
        {
          exe: "{blender}",
          exeArgs: "{blenderArgs}",
          argsBefore: [],
          blendfile: settings.blendfile,
          args: sceneArgs(settings).concat([
            "--python-expr", setTileExpression(tile, columns, rows, settings.multilayer !== false),
            "--engine", "LAZYVIS",
            "--render-output", tilePattern(tileDir, tile),
            "--render-frame", chunk.replaceAll("-", ".."), // Blender's range notation
          ]),
        },
        frameCount(chunk),
      ));
      job.addTask(task);
      tileTasks.push(task);
    }
    // One merge per frame of the chunk, once every tile of the chunk is rendered.
    const merge = author.Task(`merge-${chunk}`, "misc");
    for (const frame of chunkFrames(chunk)) {
      const tiles = [];
      for (let tile = 0; tile < columns * rows; tile++) {
        tiles.push(withFrame(tilePattern(tileDir, tile), frame) + ".exr");
      }
      merge.addCommand(author.Command("exec", {
        exe: settings.lazyvis_cmd || "lazyvis",
        args: ["merge"].concat(tiles, ["-o", withFrame(renderOutput, frame) + ".exr"]),
      }));
    }
    for (const task of tileTasks) {
      merge.addDependency(task);
    }
    job.addTask(merge);
  }
}

// The scene to render, when the job names one.
function sceneArgs(settings) {
  return settings.scene ? ["--scene", settings.scene] : [];
}

// Python run after the file is opened: the tile's render border, cropped, its place in the stamp note,
// 32-bit float EXR output (the operator comes with the LazyVis extension).
function setTileExpression(tile, columns, rows, multilayer) {
  const output = multilayer ? "MULTILAYER" : "RGBA";
  return `import bpy; bpy.ops.lazyvis.set_tile(tile=${tile}, columns=${columns}, rows=${rows}, output='${output}')`;
}

// The tile's output, '#' for the frame number (Blender adds '.exr').
function tilePattern(tileDir, tile) {
  return path.join(tileDir, `tile_${String(tile).padStart(4, "0")}_######`);
}

// The last run of '#' of a pattern replaced by the frame number, padded to its length (Blender's rule).
function withFrame(pattern, frame) {
  const match = pattern.match(/#+(?!.*#)/);
  if (!match) {
    return pattern;
  }
  const hashes = match[0];
  const number = String(Math.abs(frame)).padStart(hashes.length, "0");
  return pattern.slice(0, match.index) + (frame < 0 ? "-" : "") + number + pattern.slice(match.index + hashes.length);
}

// The frames of a chunk as frameChunker writes it: "7" or "3-9".
function chunkFrames(chunk) {
  const parts = String(chunk).split("-").map((part) => parseInt(part, 10));
  const first = parts[0];
  const last = parts.length > 1 ? parts[1] : first;
  const frames = [];
  for (let frame = first; frame <= last; frame++) {
    frames.push(frame);
  }
  return frames;
}

function frameCount(chunk) {
  return chunkFrames(chunk).length;
}

function checkedCount(value, name) {
  const count = Number(value);
  if (!Number.isInteger(count) || count < 1 || count > 64) {
    throw `${name} must be a whole number from 1 to 64, not ${value}`;
  }
  return count;
}

// The render output path with its {timestamp} filled in, as Flamenco's own job types do.
function renderOutputPath(job) {
  const output = job.settings.render_output_path;
  if (!output) {
    throw "no render_output_path setting!";
  }
  return output.replace(/{([^}]+)}/g, (match, key) => (key === "timestamp" ? formatTimestampLocal(job.created) : match));
}
