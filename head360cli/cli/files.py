"""``head360 info`` and ``head360 inspect``: what is installed, and what a file holds."""

from __future__ import annotations

from typing import Any

import click

from head360cli.cli.base import (
    STREAM_FPS,
    InputPath,
    OutputPath,
    cli,
    common_options,
    current_settings,
    emit,
    warn,
    warn_unused,
)


@cli.command()
@common_options
def info() -> None:
    """Versions of the libraries, devices, and which model files are installed.

    \b
    Examples:
      head360 info
      head360 info --json | python -m json.tool
    """
    from head360cli.devices import resolve_device
    from head360cli.report import environment_report

    report = environment_report()
    report["device"] = str(resolve_device(current_settings().device))
    lines = [f"head360 {report['head360']}  (Python {report['python']}, {report['platform']})"]
    lines.append("packages:")
    for name, version in report["packages"].items():
        lines.append(f"  {name:<13} {version or 'not installed'}")
    lines.append("devices:")
    for d in report["devices"]:
        extra = f"{d['threads']} threads" if d["name"] == "cpu" else (
            f"{d['model']}, {d['memory_gib']} GiB")
        lines.append(f"  {d['name']:<13} {extra}")
    lines.append(f"  selected      {report['device']}")
    telemetry = {True: " (usage telemetry on)", False: " (usage telemetry off)"}.get(
        report["onnxruntime_telemetry"], "")
    lines.append(f"  onnxruntime   {', '.join(report['onnxruntime_providers']) or 'none'}"
                 f"{telemetry}")
    lines.append(f"models ({report['models_dir']}):")
    if not report["models"]:
        lines.append("  (no model files installed yet)")
    for m in report["models"]:  # names up to face_detection_yunet_2023mar.onnx
        line = f"  {m['name']:<34} {m['bytes'] / 1e6:6.2f} MB  sha256 {m['sha256'][:16]}"
        if "model_hash" in m:
            line += f"  model {m['model_hash'][:16]}"
        if "licence" in m:
            line += f"  {m['licence']}, {'verified' if m['verified'] else 'DAMAGED'}"
        lines.append(line)
    lines.append("dlib weights (face-recognition-models):")
    for key, path in report["dlib_models"].items():
        lines.append(f"  {key:<20} {'present' if path else 'MISSING'}")
    lines.append(f"shared evaluation data: {report['shared_data'] or 'not found'}")
    lines.append(f"cache: {report['cache'] or 'off (HEAD360_CACHE empty, or no home folder)'}")
    emit(report, "\n".join(lines))


def _format_stream(r: dict[str, Any]) -> str:
    lines = [
        f"{r['path']}: ARKit stream ({r['format']})",
        f"  frames       {r['frames']}",
        f"  frame rate   {r['fps']:g} fps" + (
            f" (timecodes at {r['nominal_fps']:g})" if r["nominal_fps"] else ""),
        f"  duration     {r['duration_s']:.3f} s",
        f"  blendshapes  {len(r['columns_found'])} of 52 found",
    ]
    if r["columns_missing"]:
        lines.append(f"  missing      {', '.join(r['columns_missing'])}")
    if r["columns_ignored"]:
        lines.append(f"  ignored      {', '.join(r['columns_ignored'])}")
    if "head_rotation_deg" in r:
        rot = r["head_rotation_deg"]
        lines.append("  head pose    " + ", ".join(
            f"{k} {v['min']:.1f}..{v['max']:.1f} deg" for k, v in rot.items()))
    if r.get("plot"):
        lines.append(f"  plot         {r['plot']}")
    lines.append(f"  {'blendshape':<22}{'min':>8}{'mean':>8}{'max':>8}")
    for name, s in r["blendshapes"].items():
        lines.append(f"  {name:<22}{s['min']:8.3f}{s['mean']:8.3f}{s['max']:8.3f}")
    return "\n".join(lines)


def _format_image(r: dict[str, Any]) -> str:
    return "\n".join([
        f"{r['path']}: image ({r['format']})",
        f"  size         {r['width']}x{r['height']} ({r['megapixels']} MP), mode {r['mode']}",
        f"  orientation  {r['orientation']} ({r['orientation_name']}); shown as "
        f"{r['display_size'][0]}x{r['display_size'][1]}",
        f"  frames       {r['frames']}",
        f"  colours      {_colours(r.get('colour_profile'), r.get('converted'))}",
        f"  depth        {r['bits']} bits a channel"
        + (f", values using {r['bits_used']} (read as {r['bits_used']}-bit data)"
           if r.get("bits_used") and r["bits_used"] < r["bits"] else ""),
        *([f"  tone         {r['tone']}"
           + (" (fit fits its grey; the skin's colour comes from the model)"
              if r["tone"] == "greyscale" else "")] if r.get("tone") else []),
        f"  file size    {r['bytes']} bytes",
        f"  pixels       {r.get('problem') or 'decoded without error'}",
    ])


def _format_video(r: dict[str, Any]) -> str:
    duration = "unknown" if r["duration_s"] is None else f"{r['duration_s']:g} s"
    return "\n".join([
        f"{r['path']}: video",
        f"  frames       {r['frames'] or 'unknown'} at {r['fps']:g} fps ({duration})",
        f"  size         {r['width']}x{r['height']}"
        + (f", rotated {r['rotation_deg']} degrees by its metadata" if r["rotation_deg"]
           else ""),
        f"  frame 0      {r['faces_in_frame_0']} face(s) found",
        f"  file size    {r['bytes']} bytes",
    ])


def _colours(profile: str | None, converted: bool | None) -> str:
    """How ``inspect`` names an image's colour profile, and what loading does with it."""
    if profile is None:
        return "sRGB (no colour profile)"
    if profile == "unreadable":
        return "a colour profile that cannot be read (taken as sRGB)"
    if not converted:
        return f"profile {profile!r} (sRGB's: read as it is)"
    return f"profile {profile!r} (converted to sRGB on load)"


def _format_head(r: dict[str, Any]) -> str:
    meta = r["metadata"]
    lines = [
        f"{r['path']}: head360 head file, format version {meta['format_version']}",
        f"  model        {meta['model_hash']}",
        f"  created      {meta['created']} by {meta['created_by']}",
        "  arrays:",
    ]
    for name, a in r["arrays"].items():
        shape = "x".join(map(str, a["shape"])) or "scalar"
        lines.append(f"    {name:<14} {shape:<16} {a['dtype']}")
    for key, value in meta.get("info", {}).items():
        lines.append(f"  {key:<12} {value}")
    return "\n".join(lines)


def _format_model(r: dict[str, Any]) -> str:
    fmt = r["format"]
    lines = [f"{r['path']}: {fmt} ({r['bytes']} bytes, sha256 {r['sha256'][:16]})"]
    if fmt == "head360-generator":
        lines += [f"  model hash   {r['model_hash']} ("
                  f"{'the installed generator' if r['installed'] else 'not the installed one'}"
                  f"; head files record it)",
                  f"  trained      {r['step']} steps, {r['identities']} identities, "
                  f"{r['parameters']:,} parameters"]
    elif fmt == "head360-train":
        lines.append(f"  checkpoint   step {r['step']}, {r['parameters']:,} parameters")
    elif fmt == "head360-bilinear":
        lines.append(f"  model hash   {r['model_hash']} (head files record it)")
        lines += [f"  {k:<14} {'x'.join(map(str, v)) or 'scalar'}"
                  for k, v in r["arrays"].items()]
    elif fmt in ("head360-onnx", "onnx"):
        lines += [f"  input        {k} {v}" for k, v in r["inputs"].items()]
        lines += [f"  output       {k} {v}" for k, v in r["outputs"].items()]
        for key, value in (r["export"] or {}).items():
            lines.append(f"  {key:<12} {value}")
    else:  # the hair prior
        lines.append(f"  network      {r['parameters']:,} parameters")
    for key in ("generator_config", "train_config", "config"):
        for k, v in (r.get(key) or {}).items():
            lines.append(f"  {k:<12} {v}")
    return "\n".join(lines)


def _format_mesh(r: dict[str, Any]) -> str:
    if r["format"] == "obj":
        return (f"{r['path']}: Wavefront OBJ ({r['bytes']} bytes)\n"
                f"  geometry     {r['vertices']} vertices, {r['triangles']} triangles, "
                f"{r['uvs']} texture coordinates, {r['normals']} normals\n"
                f"  materials    {', '.join(r['material_libraries']) or 'none'}")
    lines = [f"{r['path']}: glTF binary ({r['bytes']} bytes"
             + (f", written by {r['generator']})" if r["generator"] else ")")]
    for m in r["meshes"]:
        targets = m["morph_targets"]
        named = m["morph_target_names"]
        lines.append(f"  mesh {m['name'] or '(unnamed)':<8} {m['vertices']} vertices, "
                     f"{m['triangles']} triangles, {targets} morph targets"
                     + (f" ({named[0]} ... {named[-1]})" if named else ""))
    for t in r["textures"]:
        size = "x".join(map(str, t["size"])) if t["size"] else "size unknown"
        lines.append(f"  texture      {size} {t['mime'] or ''}".rstrip())
    return "\n".join(lines)


@cli.command()
@click.argument("file", type=InputPath(dir_okay=False, allow_dash=True))
@click.option("--on-bad", type=click.Choice(["error", "skip", "hold"]), default="error",
              show_default=True, help="ARKit streams: what to do with NaN, empty or "
              "non-numeric cells and malformed rows.")
@STREAM_FPS
@click.option("--plot", type=OutputPath(dir_okay=False), default=None,
              help="ARKit streams: also draw the most active blendshapes and the head "
              "rotation over time into this PNG.")
@common_options
def inspect(file: str, on_bad: str, stream_fps: float | None, plot: str | None) -> None:
    """Tell what FILE is and holds: an ARKit stream, an image, a head file, a model file
    or an exported mesh.

    For an ARKit CSV stream: frames, frame rate, duration, columns found, missing or
    ignored, and min/mean/max per blendshape. For an image: size, mode, EXIF orientation,
    and whether its pixels decode.
    For a head file: its metadata and arrays. For head360's model files (generator
    weights, training checkpoints, the hair prior, the bilinear model, ONNX graphs): their
    format, configuration and the model hash head files record; nothing in them is run.
    For a .glb: its meshes, morph targets and textures; for an .obj, counts of its
    records. FILE may be - (standard input) or a pipe (<(...)), whose content says which
    it is.

    \b
    Examples:
      head360 inspect examples/smile_blink_livelinkface.csv
      head360 inspect photo.jpg --json
      head360 inspect take.csv --plot take.png
      head360 inspect models/generator.pt     which generator, trained how long
      head360 inspect me.glb                  morph targets and texture of an export
      head360 inspect clip.mp4                frames, rate, size, a face in frame 0
      cat take.csv | head360 inspect - --on-bad skip
    """
    from head360cli.report import inspect_file

    result = inspect_file(file, on_bad=on_bad, plot=plot, fps=stream_fps)
    if result["kind"] != "arkit_stream":
        what = {"image": "an image", "head": "a head", "model": "a model file",
                "mesh": "a mesh", "video": "a video"}[result["kind"]]
        warn_unused(("on_bad", "stream_fps"), f"for {what}")
    for w in result.get("warnings", []):
        warn(w)
    formatter = {"arkit_stream": _format_stream, "image": _format_image,
                 "head": _format_head, "model": _format_model,
                 "mesh": _format_mesh, "video": _format_video}[result["kind"]]
    emit(result, formatter(result))
