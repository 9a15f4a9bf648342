"""The commands that make the models: ``synth`` (the corpus), ``build-model``,
``train`` (the generator) and ``train-hair-prior``."""

from __future__ import annotations

import math
import os
from pathlib import Path
from typing import Any

import click

from head360cli.cli.base import (
    InputPath,
    OutputPath,
    cli,
    common_options,
    cpu_only_warning,
    current_settings,
    emit,
    warn,
    warn_unused,
)
from head360cli.errors import BadInputError


@cli.command()
@click.argument("outdir", type=OutputPath(file_okay=False))
@click.option("--identities", "-n", default=100, show_default=True,
              help="Identities to write.")
@click.option("--expressions", "-e", default=4, show_default=True,
              help="Per identity: neutral + (E-1) ARKit shapes at weight 1, rotating over "
              "identities; 53 = all 52 for everyone.")
@click.option("--views", "-v", default=24, show_default=True,
              help="Cameras per expression from the 72-camera rig (72 = all).")
@click.option("--size", default=256, show_default=True, help="Image width and height.")
@click.option("--seed", type=click.IntRange(min=0), default=0, show_default=True,
              help="Corpus seed.")
@click.option("--split", type=click.Choice(["train", "test"]), default="train",
              show_default=True, help="test: held-out identities from other seeds.")
@click.option("--start", default=0, show_default=True,
              help="Index of the first identity (write a split in parts).")
@click.option("--samples", type=click.Choice(["1", "2", "4"]), default="2",
              show_default=True, help="Antialiasing samples per pixel.")
@click.option("--preview", is_flag=True,
              help="Only write contact sheets (identities x views, the 52 expressions, "
              "the 30 hairstyles) into OUTDIR.")
@click.option("--skin-scan", type=InputPath(exists=True, file_okay=False), default=None,
              help="Folder of a head scan (head.obj, lambertian.jpg) whose skin detail "
                   "every head takes, e.g. ../shared/assets/lps_head_scan.")
@click.option("--soft-hair", is_flag=True,
              help="Hairlines that follow each style's line and thin out at the edge.")
@common_options
def synth(outdir: str, identities: int, expressions: int, views: int, size: int, seed: int,
          split: str, start: int, samples: str, preview: bool, skin_scan: str | None,
          soft_hair: bool) -> None:
    """Write the SynHead-P synthetic head corpus (deterministic from --seed) into OUTDIR.

    Each view is rendered with and without hair, with hair and face masks; index.jsonl
    lists identity, expression weights, hairstyle, hair colour and camera for every image.
    An interrupted run resumes: finished identities are skipped.

    \b
    Examples:
      head360 synth corpus/                       100 identities x 4 expressions x 24 views
      head360 synth corpus/ --split test -n 10    10 held-out identities
      head360 synth corpus/ -n 100 -e 53 -v 72    the full SynHead100-sized corpus
      head360 synth previews/ --preview           contact sheets only
      head360 synth corpus/ --skin-scan ../shared/assets/lps_head_scan --soft-hair
    """
    from head360cli.progress import progress_bar

    cpu_only_warning("synth", "renders")
    settings = current_settings()
    if preview:
        from head360cli.synth.corpus import write_previews

        paths = write_previews(outdir, seed=seed, split=split, skin_scan=skin_scan or "",
                               soft_hair=soft_hair)
        emit({"previews": paths}, "\n".join(f"wrote {p}" for p in paths))
        return
    from head360cli.synth.corpus import CorpusConfig, write_corpus

    cfg = CorpusConfig(identities=identities, expressions=expressions, views=views,
                       size=size, seed=seed, split=split, samples=int(samples), start=start,
                       skin_scan=skin_scan or "", soft_hair=soft_hair)
    summary = write_corpus(
        cfg, outdir,
        progress=lambda it, total: progress_bar(it, total, "identities",
                                                enabled=not settings.quiet))
    # Two images (with and without hair) per view written this run; skipped ones cost nothing.
    per_view = summary["seconds"] / max(1, 2 * summary["views_written"])
    summary["ms_per_image_all_in"] = round(1000 * per_view, 1)  # incl. building heads
    emit(summary, f"wrote {summary['identities_written']} identities "
                   f"({summary['identities_skipped']} already there), {summary['views']} "
                   f"views in the index, {summary['seconds']:.1f} s -> {summary['index']}")


@cli.command("build-expressions")
@click.argument("ict", type=InputPath(exists=True))
@click.option("-o", "--out", default=None, type=OutputPath(dir_okay=False),
              help="Output file (default: expressions.npz in the models folder).")
@common_options
def build_expressions_cmd(ict: str, out: str | None) -> None:
    """Carry ICT-FaceKit's scanned ARKit expressions onto the head template: the
    displacement fields that SynHead-P's heads move their skin, lips and jaw by in a
    model built with head360 build-model --expressions scanned.

    ICT is ICT-FaceKit's folder or its light npz. A scanned model needs its own landmark
    map (head360 build-landmark-map, written beside it with -o).

    \b
    Example:
      head360 build-expressions ../shared/data/ict-facekit
    """
    from head360cli.synth.ict import build_expressions

    target, sha, meta = _write_fields(build_expressions, ict, out, "expressions.npz")
    emit({"out": str(target), "sha256": sha, "bytes": target.stat().st_size, **meta},
         f"wrote {target} ({target.stat().st_size / 1e3:.0f} kB, sha256 {sha[:16]}); "
         f"landmarks {meta['landmark_error_mm_before_warp']} mm apart before the warp, "
         f"jaw turns {meta['jaw_rotation_degrees']['jawOpen']} degrees")


def _write_fields(build, ict: str, out: str | None, default: str
                  ) -> tuple[Path, str, dict]:
    """Check the output's name, then build the fields from ICT-FaceKit's files with
    ``build`` and write them to ``out`` (default: ``default`` in the models folder).
    Returns the path, the file's SHA-256 and the fields' meta."""
    from head360cli.paths import models_dir
    from head360cli.synth.expressions import save_fields

    target = Path(out) if out else models_dir() / default
    if target.suffix.lower() != ".npz":
        raise BadInputError(f"expected an output ending in .npz, found {str(target)!r}")
    fields = build(ict)
    return target, save_fields(fields, target), fields["meta"]


@cli.command("build-identities")
@click.argument("ict", type=InputPath(exists=True))
@click.option("-o", "--out", default=None, type=OutputPath(dir_okay=False),
              help="Output file (default: identities.npz in the models folder).")
@common_options
def build_identities_cmd(ict: str, out: str | None) -> None:
    """Carry ICT-FaceKit's 100 scanned identity components onto the head template: the
    shape space of a model built with head360 build-model --identity-space scanned.

    ICT is ICT-FaceKit's folder or its light npz.

    \b
    Example:
      head360 build-identities ../shared/data/ict-facekit
    """
    from head360cli.synth.ict import build_identities

    target, sha, meta = _write_fields(build_identities, ict, out, "identities.npz")
    emit({"out": str(target), "sha256": sha, "bytes": target.stat().st_size, **meta},
         f"wrote {target} ({target.stat().st_size / 1e6:.1f} MB, sha256 {sha[:16]}): "
         f"{meta['count']} identity components")


@cli.command("build-model")
@click.option("--corpus", type=click.Choice(["synthead-p", "ict", "synthead100"]),
              default="synthead-p", show_default=True, help="Where the meshes come from.")
@click.option("--path", type=InputPath(exists=True), default=None,
              help="ICT-FaceKit npz/folder or SynHead100-style folder.")
@click.option("--identities", "-n", default=100, show_default=True,
              help="Training identities.")
@click.option("--rank", default=50, show_default=True, help="Identity codes kept (HOSVD).")
@click.option("--seed", type=click.IntRange(min=0), default=0, show_default=True,
              help="SynHead-P seed.")
@click.option("--held-out", default=20, show_default=True,
              help="Identities kept out of the model to measure it.")
@click.option("-o", "--out", default=None, type=OutputPath(dir_okay=False),
              help="Output .npz (default: models/bilinear.npz for SynHead-P; required for "
              "external corpora, which are never shipped).")
@click.option("--calibrate", type=InputPath(exists=True, file_okay=False), default=None,
              help="Folder of dlib landmark XML files: learn where the 68 landmarks sit on "
              "the template from those faces.")
@click.option("--expressions", type=click.Choice(["procedural", "scanned"]),
              default="procedural", show_default=True,
              help="SynHead-P's blendshapes: the procedural ones (what the shipped model and "
                   "generator use) or ICT-FaceKit's scanned ones (head360 build-expressions).")
@click.option("--identity-space", type=click.Choice(["sculpted", "scanned"]),
              default="sculpted", show_default=True,
              help="SynHead-P's identities: the procedural sculpt's, or ICT-FaceKit's scanned "
                   "shape space (head360 build-identities).")
@common_options
def build_model_cmd(corpus: str, path: str | None, identities: int, rank: int, seed: int,
                    held_out: int, out: str | None, calibrate: str | None,
                    expressions: str, identity_space: str) -> None:
    """Build the bilinear head model (identity HOSVD, 52 ARKit blendshapes kept).

    \b
    Examples:
      head360 build-model --calibrate ../shared/data/faces  models/bilinear.npz
      head360 build-model --expressions scanned --calibrate ../shared/data/faces -o m/bilinear.npz
      head360 build-model --expressions scanned --identity-space scanned -o m/bilinear.npz
      head360 build-model --corpus ict --path ../shared/data/ict-facekit -o ict.npz
    """
    from head360cli.mesh.build import build_model

    cpu_only_warning("build-model", "builds")
    if out is None:
        if corpus != "synthead-p":
            from head360cli.errors import BadInputError

            raise BadInputError(f"--corpus {corpus} needs -o: external corpora are not "
                                "written into models/")
        from head360cli.paths import models_dir

        out = str(models_dir() / "bilinear.npz")
    s = build_model(corpus, path, identities, rank, seed, out, held_out, calibrate,
                    expressions, identity_space)
    lines = [f"wrote {s['out']} ({s['bytes'] / 1e6:.1f} MB, sha256 {s['sha256'][:16]}) from "
             f"{s['identities']} {corpus} identities, rank {s['rank']}, {s['seconds']} s",
             "reconstruction error, all 53 meshes per identity (mean / p99 / max mm):",
             "  training  " + " / ".join(str(v) for v in s["train_error"].values())]
    if "held_out_error" in s:
        lines.append(f"  held out ({s['held_out']}) " + " / ".join(
            str(v) for v in s["held_out_error"].values()))
    emit(s, "\n".join(lines))


PRESETS = {
    "cpu": {},
    "hexplane": {"renderer": "hexplane", "texture_res": 128, "refine_width": 32},
    "gpu": {"renderer": "hexplane", "texture_res": 256, "plane_res": 128, "render_res": 128,
            "samples": 12, "hidden": 128, "refine_width": 64, "generator_width": 256},
    "tiny": {"texture_res": 16, "render_res": 16, "image_res": 32, "hidden": 16,
             "refine_width": 8, "generator_width": 32, "hair_texture_res": 8,
             "pixel_samples": 1},
    "tiny-hexplane": {"renderer": "hexplane", "texture_res": 16, "plane_res": 16,
                      "render_res": 16, "image_res": 32, "samples": 4, "hidden": 16,
                      "refine_width": 8, "generator_width": 32, "hair_texture_res": 8},
}
"""Generator configurations by ``--preset``: ``cpu`` the deferred generator made for two
CPU cores (the default), ``hexplane`` and ``gpu`` the paper's hex-plane generator at a
CPU and a GPU size, ``tiny`` and ``tiny-hexplane`` for tests."""

RECIPES = {
    "cpu": {"steps": 100000, "minutes": 90.0, "batch": 8, "group": 4, "workers": 2},
}
"""Training settings a preset brings, where the command line does not give them: the
``cpu`` recipe trains the shipped generator on 2 cores in under 2 hours (its model card
says how long it took)."""


@cli.command()
@click.argument("run_dir", type=OutputPath(file_okay=False))
@click.option("--preset", type=click.Choice(list(PRESETS)), default="cpu", show_default=True,
              help="Generator: cpu (the deferred generator and its recipe: under 2 hours "
                   "on 2 cores), hexplane or gpu (the paper's hex-planes), tiny (tests).")
@click.option("--steps", default=3000, show_default=True,
              help="Optimiser steps (the cpu recipe: 100000, bounded by its minutes).")
@click.option("--minutes", default=0.0, show_default=True,
              help="Stop after this much training time (0: no limit; the cpu recipe: 90).")
@click.option("--batch", default=4, show_default=True,
              help="Views per step and process (the cpu recipe: 8).")
@click.option("--identities", "-n", default=100, show_default=True,
              help="SynHead-P training heads.")
@click.option("--seed", type=click.IntRange(min=0), default=0, show_default=True,
              help="Corpus and training seed.")
@click.option("--planes", type=click.Choice(["hex", "tri"]), default="hex", show_default=True,
              help="Feature planes: six (hex) or three (tri, the ablation).")
@click.option("--no-refine", is_flag=True, help="Without the RefineNet (the ablation).")
@click.option("--no-detach", is_flag=True,
              help="Without hair detachment: every view with its hair (the ablation).")
@click.option("--no-hair", is_flag=True, help="Head branch only, trained on bald views.")
@click.option("--lr", default=2e-3, show_default=True, help="Learning rate of the networks.")
@click.option("--group", default=1, show_default=True,
              help="Views per head in a batch, rendered together (faster data; the cpu "
                   "recipe: 4).")
@click.option("--workers", default=1, show_default=True,
              help="Processes that build the corpus heads before training (the cpu "
                   "recipe: 2).")
@click.option("--featured-share", default=0.25, show_default=True,
              help="Share of expressions with a blink or jawOpen at 0.7-1 on top (random "
                   "expressions rarely close the eyes).")
@click.option("--export", "export", type=OutputPath(dir_okay=False), default=None,
              help="Also write the shippable weights here (e.g. models/generator.pt).")
@click.option("--init", "init", type=InputPath(dir_okay=False, exists=True), default=None,
              help="Start a new run from these generator weights (their configuration "
                   "replaces --preset and the ablation flags).")
@click.option("--skin-scan", type=InputPath(exists=True, file_okay=False), default=None,
              help="Train on corpus heads whose skin takes this head scan's detail.")
@click.option("--soft-hair", is_flag=True,
              help="Train on soft hairlines (the weights then fit their hair so).")
@common_options
def train(run_dir: str, preset: str, steps: int, minutes: float, batch: int,
          identities: int, seed: int, planes: str, no_refine: bool, no_detach: bool,
          no_hair: bool, lr: float, group: int, workers: int, featured_share: float,
          export: str | None, init: str | None, skin_scan: str | None,
          soft_hair: bool) -> None:
    """Train the generator on SynHead-P (resumes a run folder that has a checkpoint).

    \b
    Examples:
      head360 train runs/cpu --export models/generator.pt
      head360 train runs/hex --preset hexplane --planes tri --minutes 20
      head360 train runs/gpu --preset gpu --device cuda --batch 16 --steps 6000
      head360 train runs/more --init models/generator.pt --device cuda --minutes 10
      torchrun --nproc_per_node 2 -m head360cli train runs/ddp --steps 100
    """
    from head360cli.devices import resolve_device
    from head360cli.model.config import GeneratorConfig
    from head360cli.model.train import CHECKPOINT, TrainConfig, save_generator
    from head360cli.model.train import train as run_training

    ctx = click.get_current_context()
    for name, value in RECIPES.get(preset, {}).items():
        if ctx.get_parameter_source(name) != click.core.ParameterSource.COMMANDLINE:
            steps, minutes, batch, group, workers = (
                value if name == key else current for key, current in
                (("steps", steps), ("minutes", minutes), ("batch", batch),
                 ("group", group), ("workers", workers)))

    if steps < 1 or batch < 1 or identities < 1:
        raise BadInputError(f"expected --steps, --batch and --identities >= 1, found "
                            f"{steps}, {batch} and {identities}")
    if not 0.0 <= featured_share <= 1.0:
        raise BadInputError(f"expected --featured-share in [0, 1], found {featured_share}")
    if group < 1 or workers < 1:
        raise BadInputError(f"expected --group and --workers >= 1, found {group} and {workers}")
    _check_rate_and_minutes(lr, minutes)
    device = str(resolve_device(current_settings().device))
    resuming = (Path(run_dir) / CHECKPOINT).is_file()
    if resuming:  # the checkpoint's configuration replaces all but these
        warn_unused(("preset", "planes", "no_refine", "no_hair", "batch", "identities", "seed",
                     "lr", "group", "workers", "featured_share", "no_detach", "init",
                     "skin_scan", "soft_hair"),
                f"when resuming {run_dir} (its checkpoint's configuration is used)")
    elif init is not None:  # the initial weights' configuration replaces these
        warn_unused(("preset", "planes", "no_refine", "no_hair"),
                "with --init (the weights' own configuration is used)")
    gen_cfg = GeneratorConfig(**PRESETS[preset], planes=planes, refine=not no_refine,
                              hair=not no_hair)
    cfg = TrainConfig(identities=identities, seed=seed, steps=steps, minutes=minutes,
                      batch=batch, lr=lr, detach=not no_detach, group=group,
                      workers=workers, featured_share=featured_share, init=init or "",
                      skin_scan=skin_scan or "", soft_hair=soft_hair)
    last = run_training(run_dir, cfg, gen_cfg, device=device, progress=not current_settings().quiet)
    result: dict[str, Any] = {"run": run_dir, "last": last}
    trained = "l1" in last  # a resumed run at --steps already trains nothing
    result["trained"] = trained
    if not trained:
        warn(f"{run_dir} is at step {last['step']} already (--steps {steps}): nothing was "
              "trained; give a larger --steps to go on")
    if export and int(os.environ.get("RANK", "0")) == 0:
        result["export"] = save_generator(Path(run_dir) / CHECKPOINT, export)
    emit(result, (f"trained to step {last['step']}: L1 {last['l1']}" if trained else
                   f"at step {last['step']}, as before")
          + (f"; wrote {export}" if export else ""))


def _check_rate_and_minutes(lr: float, minutes: float) -> None:
    """A training command's ``--lr`` (finite, above 0) and ``--minutes`` (0: no limit)."""

    if not (math.isfinite(lr) and lr > 0):
        raise BadInputError(f"expected a finite --lr > 0, found {lr}")
    if not (math.isfinite(minutes) and minutes >= 0):
        raise BadInputError(f"expected --minutes >= 0 (0: no limit), found {minutes}")


@cli.command("train-hair-prior")
@click.option("-o", "--out", default=None, type=OutputPath(dir_okay=False),
              help="Output weights (default: models/hair_prior.pt).")
@click.option("--heads", default=600, show_default=True, help="Corpus heads rendered.")
@click.option("--views", default=5, show_default=True, help="Random views per head.")
@click.option("--seed", type=click.IntRange(min=0), default=3, show_default=True,
              help="Corpus and training seed (the bench uses 0, parse development 1 and 2).")
@click.option("--steps", default=2400, show_default=True, help="Optimiser steps.")
@click.option("--minutes", default=0.0, show_default=True,
              help="Also stop after this much training time (0: no limit).")
@click.option("--batch", default=24, show_default=True, help="Crops per step.")
@click.option("--width", default=16, show_default=True,
              help="Channels of the network's first level.")
@click.option("--frame-share", default=0.0, show_default=True,
              help="Share of crops cut to a random rectangle with its edge repeated beyond "
                   "it, as a photo's edge is in the crop of a face that fills the photo.")
@click.option("--hat-share", default=0.0, show_default=True,
              help="Share of crops with a hat drawn over the head, not hair in the target.")
@click.option("--init", "init", default=None, type=InputPath(dir_okay=False),
              help="Start from this hair prior's weights (fine-tuning) instead of random "
                   "ones.")
@click.option("--lr", default=2e-3, show_default=True,
              help="Learning rate at the start (it decays linearly to 5 % of it).")
@common_options
def train_hair_prior_cmd(out: str | None, heads: int, views: int, seed: int, steps: int,
                         minutes: float, batch: int, width: int, frame_share: float,
                         hat_share: float, init: str | None, lr: float) -> None:
    """Train the learned hair prior that guides hair parsing, on corpus renders.

    About 3 minutes of rendering and 20 of training on 2 CPU cores with the defaults.
    Ctrl-C stops after the step it is on with a checkpoint (OUT's name with .resume.pt,
    also written every 100 steps); the same command then resumes from it.

    \b
    Examples:
      head360 train-hair-prior                      writes models/hair_prior.pt
      head360 train-hair-prior --steps 200 -o try.pt
      head360 train-hair-prior --init models/hair_prior.pt --steps 600 --lr 5e-4 -o tuned.pt
    """
    from head360cli.devices import resolve_device
    from head360cli.fitting.hair_prior import FILE_NAME, HairPriorConfig, save_hair_prior
    from head360cli.fitting.hair_prior_train import (
        HairPriorTrainConfig,
        resume_path,
        train_hair_prior,
    )

    if min(heads, views, steps, batch, width) < 1:
        raise BadInputError(f"expected --heads, --views, --steps, --batch and --width >= 1, "
                            f"found {heads}, {views}, {steps}, {batch} and {width}")
    for name, share in (("--frame-share", frame_share), ("--hat-share", hat_share)):
        if not 0.0 <= share <= 1.0:
            raise BadInputError(f"expected {name} in [0, 1], found {share}")
    _check_rate_and_minutes(lr, minutes)
    if init is not None and not Path(init).is_file():
        raise BadInputError(f"hair prior {init!r} (--init) does not exist")
    if out is None:
        from head360cli.paths import models_dir

        out = str(models_dir() / FILE_NAME)
    if Path(out).suffix.lower() != ".pt":
        raise BadInputError(f"expected a hair prior output ending in .pt, found {out!r}")
    from head360cli.io.atomic import check_file_target

    checkpoint = resume_path(out)
    for target in (out, checkpoint):  # an existing, writable folder: before the renders
        check_file_target(target)
    device = str(resolve_device(current_settings().device))
    if device != "cpu":
        warn("train-hair-prior trains on the CPU (the renders are CPU work)")
    cfg = HairPriorTrainConfig(heads=heads, views=views, seed=seed, steps=steps,
                               minutes=minutes, batch=batch, frame_share=frame_share,
                               hat_share=hat_share, init=init or "", lr=lr)
    quiet = current_settings().quiet
    prior, summary = train_hair_prior(
        cfg, HairPriorConfig(width=width), progress=not quiet, checkpoint=checkpoint,
        log=None if quiet else (lambda line: click.echo(line, err=True)))
    save_hair_prior(prior, out, summary)
    checkpoint.unlink(missing_ok=True)  # the run is done: nothing to resume
    summary["out"] = out
    emit(summary, f"trained the hair prior for {summary['steps']} steps "
          f"({summary['render_seconds']} s rendering, {summary['train_seconds']} s training, "
          f"final loss {summary['final_loss']}); wrote {out}")


@cli.command("build-skin-detail")
@click.argument("scan", type=InputPath(exists=True, file_okay=False))
@click.option("-o", "--out", default=None, type=OutputPath(dir_okay=False),
              help="Output file (default: skin_detail.npz in the models folder).")
@click.option("--size", type=click.IntRange(16, 2048), default=256, show_default=True,
              help="Texels a side (the generator's texture size).")
@common_options
def build_skin_detail_cmd(scan: str, out: str | None, size: int) -> None:
    """Carry a real head scan's fine skin detail (pores, stubble, small marks) onto the
    head template's texture layout, for the skin a fit's photo does not show.

    The scan is laid over the mean head by its landmarks (about 40 s, then cached); the
    detail is the scan's colour over its own 1.5-texel blur. The shipped file was made
    from Lee Perry-Smith's scan (CC BY 3.0).

    \b
    Example:
      head360 build-skin-detail ../shared/assets/lps_head_scan
    """
    from head360cli.paths import models_dir
    from head360cli.synth.skin import SKIN_DETAIL_FILE, write_skin_detail

    result = write_skin_detail(scan, out or models_dir() / SKIN_DETAIL_FILE, size)
    emit(result, f"wrote {result['out']} ({size}x{size}, {result['bytes'] / 1e3:.0f} kB)")


@cli.command("build-landmark-map")
@click.argument("folder", type=InputPath(exists=True, file_okay=False))
@click.option("-o", "--out", default=None, type=OutputPath(file_okay=False),
              help="Output folder (default: the models folder).")
@common_options
def build_landmark_map_cmd(folder: str, out: str | None) -> None:
    """Learn how the 68 iBUG landmarks are read from the 478-point face mesh, and where
    the mesh's points sit on the head template.

    Each iBUG point becomes a fixed combination of a few mesh points, fitted to dlib's
    68-point predictions on the photos in FOLDER (searched recursively; at least 20
    faces); then each mesh point is placed on the head's surface where fits of those
    photos project it best. Writes ibug68_map.npz and face_mesh_on_head.npz. The
    shipped files were made from the London set's 124 portraits.

    \b
    Example:
      head360 build-landmark-map ../shared/data/faces/london
    """
    import numpy as np

    from head360cli.fitting.calibrate import DENSE_FILE, build_ibug68_map
    from head360cli.io.atomic import atomic_paths
    from head360cli.paths import models_dir
    from head360cli.perception.ibug68 import IBUG68_FILE

    result = build_ibug68_map(folder)
    folder_out = Path(out) if out else models_dir()
    targets = (folder_out / IBUG68_FILE, folder_out / DENSE_FILE)
    with atomic_paths(*targets) as (map_tmp, dense_tmp):
        with open(map_tmp, "wb") as fh:
            np.savez_compressed(fh, index=result["index"].astype(np.int16),
                                weight=result["weight"].astype(np.float32))
        with open(dense_tmp, "wb") as fh:
            np.savez_compressed(fh, tri=result["tri"].astype(np.int32),
                                bary=result["bary"].astype(np.float32),
                                error=result["error"].astype(np.float32),
                                use=result["use"], model=np.array(result["model"]))
    reg = result["registration"]
    emit({"out": [str(t) for t in targets], "faces": result["faces"],
          "train_nme_percent": round(100 * result["train_nme"], 3),
          "dense_points": int(result["use"].sum()),
          "registration_error_percent": round(100 * reg["mesh_error"], 3)},
         f"landmark map and face-mesh registration from {result['faces']} faces (map NME "
         f"against dlib {100 * result['train_nme']:.2f} %; {int(result['use'].sum())} mesh "
         f"points placed, mean error {100 * reg['mesh_error']:.2f} % of the face) -> "
         f"{folder_out}")
