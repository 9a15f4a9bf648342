"""``head360 bench``: the speed-against-error benchmarks, one subcommand each, and
``bench all`` and ``bench summary`` over them."""

from __future__ import annotations

import sys
from pathlib import Path

import click

from head360cli.cli.base import (
    BENCH_OUT,
    InputPath,
    OutputPath,
    check_size,
    cli,
    common_options,
    cpu_only_warning,
    current_settings,
    emit,
    warn,
)
from head360cli.errors import BadInputError


def _save_and_emit(result: dict, md: str, out_dir: str, name: str) -> None:
    """Write a benchmark's ``NAME.json`` and ``NAME.md`` into ``out_dir`` and print the
    table (or the JSON, with ``--json``) with the files written."""
    from head360cli.bench.report import save

    result["files"] = save(result, md, out_dir, name)
    emit(result, md + f"\n\nwrote {', '.join(result['files'])}")


@cli.group("bench")
def bench_group() -> None:
    """Speed-against-error benchmarks; each writes JSON and a Markdown table.

    \b
    Examples:
      head360 bench all                      every stage, then bench.md and bench.png
      head360 bench all --quick              the same, small (minutes)
      head360 bench summary                  the table and plot from results already there
      head360 bench synth -n 10 --out bench/
    """


@bench_group.command("synth")
@click.option("--identities", "-n", default=100, show_default=True,
              help="Identities in the timed corpus subset.")
@click.option("--pose-heads", default=8, show_default=True,
              help="Held-out heads whose pose is read from their renders' landmarks "
                   "(0: skip).")
@click.option("--detector", type=click.Choice(["auto", "hog"]), default="auto",
              show_default=True, help="Landmarks for the pose: the face mesh or dlib.")
@click.option("--skin-scan", type=InputPath(exists=True, file_okay=False), default=None,
              help="Also read the pose of heads with this head scan's skin.")
@BENCH_OUT
@common_options
def bench_synth_cmd(identities: int, pose_heads: int, detector: str, skin_scan: str | None,
                    out_dir: str) -> None:
    """Corpus renderer: ms per 256x256 view by antialiasing samples and batch size, and
    the time to write a corpus subset (target: at most 50 ms per view on 2 cores); the
    heads' face proportions against ICT-FaceKit's; the pose the fit's landmarks read on
    corpus renders (goal: within 3 degrees).

    \b
    Example:
      head360 bench synth --skin-scan ../shared/assets/lps_head_scan
    """
    from head360cli.bench.synth import bench_synth

    cpu_only_warning("bench synth")
    if identities < 1 or pose_heads < 0:
        raise BadInputError(f"expected --identities >= 1 and --pose-heads >= 0, found "
                            f"{identities} and {pose_heads}")
    result, md = bench_synth(identities=identities, pose_heads=pose_heads,
                             skin_scan=skin_scan or "", detector=detector)
    _save_and_emit(result, md, out_dir, "synth")


@bench_group.command("fit-shape")
@click.option("--trials", default=200, show_default=True,
              help="Synthetic faces (random identity, expression and pose).")
@BENCH_OUT
@common_options
def bench_fit_shape_cmd(trials: int, out_dir: str) -> None:
    """Landmark shape fit: vertex and pose error on synthetic faces by yaw; on the real
    photos in ../shared/data, NME of the detected (face mesh and dlib) and the fitted
    landmarks by yaw, faces found per yaw by each detector, and detection and fit time."""
    from head360cli.bench.fit_shape import bench_fit_shape

    cpu_only_warning("bench fit-shape")
    if trials < 1:  # zero trials failed after the real-photo part, as an internal error
        raise BadInputError(f"expected --trials >= 1, found {trials}")
    result, md = bench_fit_shape(trials=trials)
    _save_and_emit(result, md, out_dir, "fit_shape")


@bench_group.command("fit")
@click.option("--identities", default=2, show_default=True,
              help="Held-out synthetic heads fitted from one frontal render.")
@click.option("--preset", "presets", multiple=True, type=click.Choice(["fast", "quality"]),
              help="Presets to measure (repeat; default both).")
@click.option("--no-sweep", is_flag=True, help="Skip the inversion-steps sweep.")
@click.option("--stability", default=3, show_default=True,
              help="Noisy copies of each stability photo (see --stability-photos) "
                   "fitted again (0: none).")
@click.option("--stability-photos", default=1, show_default=True,
              help="How many of the real photos get --stability noisy copies each; with "
                   "several, the means over them are compared draw by draw.")
@click.option("--synthetic-noise", default=0, show_default=True,
              help="Fit the synthetic heads again from this many copies of their "
                   "renders, each value moved by one grey level (0: none).")
@click.option("--corpus-seed", default=0, show_default=True,
              help="Corpus seed of the held-out synthetic heads (0: the bench's; others "
                   "for development).")
@click.option("--weights", "weights", multiple=True, type=InputPath(dir_okay=False),
              help="Generator weights to measure instead of the installed ones; repeat to "
                   "compare them in one run (labelled by file name).")
@BENCH_OUT
@common_options
def bench_fit_cmd(identities: int, presets: tuple[str, ...], no_sweep: bool,
                  stability: int, stability_photos: int, synthetic_noise: int,
                  corpus_seed: int, weights: tuple[str, ...], out_dir: str) -> None:
    """Single-image fitting: hair parsing IoU, hairstyle accuracy, 72-view PSNR/SSIM of
    synthetic fits, face PSNR and dlib descriptor distance on real photos, time, and how
    far a fit moves when the photo moves by one grey level.

    \b
    Examples:
      head360 bench fit
      head360 bench fit --preset fast --identities 1 --no-sweep --stability 0
      head360 bench fit --preset fast --identities 6 --corpus-seed 1 --no-sweep
      head360 bench fit --preset fast --no-sweep --stability-photos 6   how far the
                                               means move with one grey level of noise
      head360 bench fit --preset quality --no-sweep --stability 0 --synthetic-noise 3
      head360 bench fit --device cuda          the fits on the GPU (dlib still needed)
      head360 bench fit --preset fast --no-sweep --stability 0 --weights old.pt \\
          --weights models/generator.pt      two generators, one run
    """
    from head360cli.bench.fit import bench_fit
    from head360cli.bench.report import per_generator
    from head360cli.devices import resolve_device

    device = str(resolve_device(current_settings().device))
    if identities < 1:
        raise BadInputError(f"expected --identities >= 1, found {identities}")
    if stability < 0:
        raise BadInputError(f"expected --stability >= 0, found {stability}")
    if stability_photos < 0:
        raise BadInputError(f"expected --stability-photos >= 0, found {stability_photos}")
    if synthetic_noise < 0:
        raise BadInputError(f"expected --synthetic-noise >= 0, found {synthetic_noise}")
    if corpus_seed < 0:
        raise BadInputError(f"expected --corpus-seed >= 0, found {corpus_seed}")
    def run(label: str | None):
        tag = f" {label}" if label else ""
        return bench_fit(identities=identities, presets=presets or ("fast", "quality"),
                         sweep=() if no_sweep else (5, 10, 20, 40), stability=stability,
                         stability_photos=stability_photos,
                         synthetic_noise=synthetic_noise,
                         corpus_seed=corpus_seed, device=device,
                         progress=None if current_settings().quiet else
                         (lambda t: click.echo(f"bench fit{tag}: {t}", err=True)))

    result, md = per_generator(weights, run)
    _save_and_emit(result, md, out_dir, "fit")


@bench_group.command("multiview")
@click.option("--preset", "presets", multiple=True, type=click.Choice(["fast", "quality"]),
              help="Presets to measure (repeat; default both).")
@click.option("--person", "people", multiple=True, type=click.IntRange(1),
              help="People of the set to fit (repeat; default all).")
@click.option("--series", "series", multiple=True, type=click.IntRange(1, 2),
              help="Photo series of each person (repeat; default 1).")
@click.option("--sheet-person", default=2, show_default=True,
              help="Whose renders the contact sheet shows.")
@click.option("--weights", "weights", multiple=True, type=InputPath(dir_okay=False),
              help="Generator weights to measure instead of the installed ones; repeat to "
                   "compare them in one run (labelled by file name).")
@BENCH_OUT
@common_options
def bench_multiview_cmd(presets: tuple[str, ...], people: tuple[int, ...],
                        series: tuple[int, ...], sheet_person: int, weights: tuple[str, ...],
                        out_dir: str) -> None:
    """360 degrees on real photos: fit each person's frontal photo, turn the head to the
    yaws of their other photos (-90 to +90 degrees) and compare: dlib descriptor distance
    render-real, faces found, the real turn's own distance, head silhouette IoU; the
    hair against the segmenter's on the real photo (IoU, colour CIEDE2000, read as hair,
    silhouette steps); and a contact sheet (real photos above, renders below). Needs
    ../shared/data/multiview.

    \b
    Examples:
      head360 bench multiview
      head360 bench multiview --preset fast --person 1 --person 2
      head360 bench multiview --series 1 --series 2 --out results/
      head360 bench multiview --preset fast --weights old.pt --weights models/generator.pt
    """
    from head360cli.bench.multiview import bench_multiview
    from head360cli.bench.report import per_generator
    from head360cli.devices import resolve_device

    device = str(resolve_device(current_settings().device))
    def run(label: str | None):
        tag = f" {label}" if label else ""
        return bench_multiview(presets=presets or ("fast", "quality"),
                               people=people or None, series=series or (1,),
                               sheet_person=sheet_person, device=device,
                               out_dir=out_dir if label is None else Path(out_dir) / label,
                               progress=None if current_settings().quiet else
                               (lambda t: click.echo(f"bench multiview{tag}: {t}", err=True)))

    result, md = per_generator(weights, run)
    _save_and_emit(result, md, out_dir, "multiview")


@bench_group.command("generator")
@click.option("--weights", "weights", multiple=True, type=InputPath(dir_okay=False),
              help="Generator weights; repeat to compare (labelled by file name). "
                   "Default: models/generator.pt.")
@click.option("--train-ids", default=6, show_default=True,
              help="Training identities scored on held-out views and hair swap.")
@click.option("--test-ids", default=2, show_default=True,
              help="Held-out identities (codes fitted with the generator frozen; 0: none).")
@click.option("--fit-steps", default=40, show_default=True,
              help="Code-fitting steps per held-out identity.")
@click.option("--cameras", default=8, show_default=True,
              help="Held-out cameras per head (of 24 around it).")
@click.option("--no-speed", is_flag=True, help="Skip the timing and the speed sweep.")
@BENCH_OUT
@click.option("--name", default="generator", show_default=True,
              help="File name of the results (<name>.json, <name>.md).")
@common_options
def bench_generator_cmd(weights: tuple[str, ...], train_ids: int, test_ids: int,
                        fit_steps: int, cameras: int, no_speed: bool, out_dir: str,
                        name: str) -> None:
    """Generator: PSNR and SSIM on held-out views, held-out identities and hair swap,
    frame time, and speed against quality for samples per ray and plane resolution.

    \b
    Examples:
      head360 bench generator
      head360 bench generator --weights a/hex.pt --weights a/tri.pt --no-speed --test-ids 0
      head360 bench generator --device cuda --train-ids 2 --test-ids 0
    """
    from head360cli.bench.generator import bench_generator
    from head360cli.devices import resolve_device

    if train_ids < 1 or test_ids < 0 or fit_steps < 0 or not 1 <= cameras <= 24:
        raise BadInputError(f"expected --train-ids >= 1, --test-ids >= 0, --fit-steps >= 0 "
                            f"and 1 <= --cameras <= 24, found {train_ids}, {test_ids}, "
                            f"{fit_steps} and {cameras}")
    device = str(resolve_device(current_settings().device))
    result, md = bench_generator(list(weights) or None, train_ids, test_ids, fit_steps,
                                 cameras, speed=not no_speed, device=device,
                                 progress=not current_settings().quiet)
    _save_and_emit(result, md, out_dir, name)


@bench_group.command("animate")
@click.option("--frames", default=120, show_default=True,
              help="Frames per throughput measurement.")
@click.option("--stride", default=3, show_default=True,
              help="Every Nth frame of the capture for expression fidelity.")
@click.option("--fidelity-size", type=int, default=None,
              help="Image size of the expression-fidelity frames (default: the "
                   "generator's, as head360 animate renders them).")
@click.option("--stream", "stream_path", type=InputPath(exists=True, dir_okay=False),
              default=None, help="ARKit CSV to drive the heads with (default: the longest "
                                 "Live Link Face capture in ../shared/data).")
@click.option("--no-memory", is_flag=True,
              help="Skip the whole-capture peak-memory run (minutes).")
@click.option("--head", "head_path", type=InputPath(exists=True, dir_okay=False),
              default=None, help="Measure this head file instead of fitting the astronaut "
                                 "photo (no fit, so no dlib unless fidelity is measured).")
@click.option("--no-fidelity", is_flag=True,
              help="Skip the expression-fidelity parts (the face tracker on frames).")
@BENCH_OUT
@common_options
def bench_animate_cmd(frames: int, stride: int, fidelity_size: int | None,
                      stream_path: str | None, no_memory: bool, head_path: str | None,
                      no_fidelity: bool, out_dir: str) -> None:
    """Animation: frames per second with and without reuse of decoded points between
    frames, against samples and precision (with PSNR), peak memory over a whole capture,
    a turning head (--head-pose), expression fidelity read with the face tracker (its
    speed and its reading of real neutral and smiling faces; per-blendshape Pearson r of
    each Live Link Face capture through the head, beside SynHead-P heads rendered with
    the same weights, and a plot, animate_fidelity.png), face PSNR across hair swaps.

    With --device cuda the heads are rendered on the GPU, and frames per second against
    frames per generator call (animate --batch) replace the reuse part, a CPU path.

    \b
    Examples:
      head360 bench animate
      head360 bench animate --frames 60 --stride 6 --no-memory
      head360 bench animate --stride 6 --fidelity-size 512
      head360 bench animate --stream examples/smile_blink_livelinkface.csv --stride 1
      head360 bench animate --device cuda --head me.h360 --no-fidelity --frames 480
    """
    from head360cli.bench.animate import bench_animate
    from head360cli.devices import resolve_device

    device = str(resolve_device(current_settings().device))
    if frames < 8 or stride < 1:
        raise BadInputError(f"expected --frames >= 8 and --stride >= 1, found {frames}, "
                            f"{stride}")
    if no_fidelity and fidelity_size is not None:
        raise BadInputError("--fidelity-size sets the size of the fidelity frames; "
                            "expected it without --no-fidelity")
    if fidelity_size is not None:
        if not 64 <= fidelity_size <= 1024:
            raise BadInputError(f"expected --fidelity-size between 64 and 1024, found "
                                f"{fidelity_size}")
        from head360cli.model.train import load_generator

        try:  # refuse now a size the generator cannot make, not after minutes of work
            load_generator()[0].image_size(fidelity_size)
        except ValueError as exc:
            raise BadInputError(f"--fidelity-size: {exc}") from None
    if head_path is not None:
        from head360cli.io.headfile import read_head
        from head360cli.paths import generator_hash

        if not Path(head_path).is_file():  # a pipe: every part opens the head again
            raise BadInputError(f"--head: expected a regular file, found {head_path!r} (a "
                                "pipe or device); the bench reads it once per part")
        read_head(head_path, expected_model_hash=generator_hash())  # now, not after minutes
    result, md = bench_animate(frames, stride, memory=not no_memory,
                               fidelity_size=fidelity_size, stream_path=stream_path,
                               device=device, head_path=head_path,
                               fidelity=not no_fidelity,
                               plot=None if no_fidelity else
                               Path(out_dir) / "animate_fidelity.png",
                               progress=None if current_settings().quiet else
                               (lambda t: click.echo(f"bench animate: {t}", err=True)))
    _save_and_emit(result, md, out_dir, "animate")


@bench_group.command("expressions")
@click.option("--head", "head_path", type=InputPath(exists=True, dir_okay=False),
              default=None, help="Measure this head file instead of fitting the astronaut "
                                 "photo.")
@click.option("--size", type=int, default=None,
              help="Image size of the frames (default: the generator's).")
@click.option("--no-corpus", is_flag=True,
              help="Skip the corpus renderer's head (the corpus's own expressions).")
@click.option("--no-real", is_flag=True,
              help="Skip reading the shared real photos (which blendshapes the tracker "
                   "reads on real faces; about a minute).")
@BENCH_OUT
@common_options
def bench_expressions_cmd(head_path: str | None, size: int | None, no_corpus: bool,
                          no_real: bool, out_dir: str) -> None:
    """Each ARKit blendshape alone at 0.25, 0.5, 0.75 and 1 on a fitted head, read back
    by the face tracker: which rise with their weight. Beside it, a SynHead-P head drawn
    by the corpus renderer, and the tracker's highest score for each on the real photos
    in ../shared/data (a blendshape never above 0.2 there is one it does not read).

    \b
    Examples:
      head360 bench expressions
      head360 bench expressions --head me.h360 --size 512 --no-corpus
    """
    from head360cli.bench.expressions import bench_expressions
    from head360cli.devices import resolve_device

    if size is not None and not 64 <= size <= 1024:
        raise BadInputError(f"expected --size between 64 and 1024, found {size}")
    device = str(resolve_device(current_settings().device))
    result, md = bench_expressions(head_path, size, corpus=not no_corpus, real=not no_real,
                                   device=device,
                                   progress=None if current_settings().quiet else
                                   (lambda t: click.echo(f"bench expressions: {t}",
                                                         err=True)))
    _save_and_emit(result, md, out_dir, "expressions")


@bench_group.command("onnx")
@click.option("--heads", default=100, show_default=True,
              help="Random heads, expressions and cameras for parity.")
@click.option("--size", default=256, show_default=True, help="Image size of the graph.")
@click.option("--samples", type=int, default=None,
              help="Samples a pixel, 1, 2 or 4 (per ray for hex-plane weights; default: "
                   "the generator's own).")
@click.option("--repeats", default=10, show_default=True,
              help="Timed frames per block.")
@click.option("--rounds", default=3, show_default=True,
              help="Timed blocks per row, the backends taking turns.")
@click.option("--onnx", "graph", default=None, type=InputPath(dir_okay=False),
              help="Use this exported graph (default: export one, about 80 seconds on "
                   "2 CPU cores).")
@BENCH_OUT
@common_options
def bench_onnx_cmd(heads: int, size: int, samples: int | None, repeats: int, rounds: int,
                   graph: str | None, out_dir: str) -> None:
    """onnxruntime against torch: largest difference over random heads, and speed.

    \b
    Examples:
      head360 bench onnx
      head360 bench onnx --heads 10 --size 128 --samples 1
      head360 bench onnx --device cuda --onnx generator.onnx   torch timed on the GPU
    """
    from head360cli.bench.onnx import bench_onnx
    from head360cli.devices import resolve_device

    if not 1 <= heads <= 10000 or not 1 <= repeats <= 1000 or not 1 <= rounds <= 100:
        raise BadInputError(f"expected --heads in 1..10000, --repeats in 1..1000 and "
                            f"--rounds in 1..100, found {heads}, {repeats} and {rounds}")
    check_size(size)
    if samples is not None and not 1 <= samples <= 64:
        raise BadInputError(f"expected --samples between 1 and 64, found {samples}")
    if graph is not None and not Path(graph).is_file():
        raise BadInputError(f"ONNX graph {graph!r} does not exist")
    progress = None if current_settings().quiet else (lambda t: click.echo(f"bench onnx: {t}",
                                                                    err=True))
    result, md = bench_onnx(heads, size, samples, repeats, graph=graph, progress=progress,
                            rounds=rounds, device=str(resolve_device(current_settings().device)))
    _save_and_emit(result, md, out_dir, "onnx")


@bench_group.command("summary")
@click.argument("folder", default="bench-results", type=InputPath(file_okay=False))
@click.option("--out", "out_dir", default=None, type=OutputPath(file_okay=False),
              help="Where bench.json, bench.md and bench.png go (default: FOLDER).")
@common_options
def bench_summary_cmd(folder: str, out_dir: str | None) -> None:
    """Every stage's speed against error in one table and plot, from the stage results.

    \b
    Examples:
      head360 bench summary
      head360 bench summary bench-results --out docs/bench
    """
    from head360cli.bench.summary import summarize

    if not Path(folder).is_dir():
        raise BadInputError(f"results folder {folder!r} does not exist")
    result, md = summarize(folder, out_dir)
    emit(result, md + f"\n\nwrote {', '.join(result['files'])}")


@bench_group.command("all")
@click.option("--out", "out_dir", default="bench-results", show_default=True,
              type=OutputPath(file_okay=False), help="Where every result goes.")
@click.option("--quick", is_flag=True,
              help="Small versions of each stage (minutes, not an hour); noisier numbers.")
@click.option("--skip", multiple=True,
              type=click.Choice(["fit-shape", "fit", "generator", "animate", "onnx",
                                 "synth"]), help="Leave a stage out (repeatable).")
@common_options
def bench_all_cmd(out_dir: str, quick: bool, skip: tuple[str, ...]) -> None:
    """Run every stage's benchmark, then the summary table and plot.

    Each stage runs in its own process; one that fails is reported and the others go on
    (exit status 1 if any failed, after the summary of the rest).

    \b
    Examples:
      head360 bench all
      head360 bench all --quick --out bench-quick
      head360 bench all --skip generator --skip synth
      head360 bench all --device cuda     fit, generator, animate and onnx on the GPU
    """
    import subprocess
    import time

    from head360cli.bench.summary import STAGE_RUNS, summarize
    from head360cli.devices import resolve_device

    device = current_settings().device
    resolve_device(device)  # a device that is not there stops it before the first stage
    # the stages that measure on a device take it; the CPU-only ones say they do not
    on = ["--device", device] if device.strip().lower() != "cpu" else []
    failed, timings = [], {}
    for stage, (full, small) in STAGE_RUNS.items():
        if stage in skip:
            continue
        cmd = [sys.executable, "-m", "head360cli", "bench", stage, "--out", out_dir,
               *(small if quick else full), *on]
        if not current_settings().quiet:
            click.echo(f"bench all: {stage}: {' '.join(cmd[3:])}", err=True)
        t0 = time.perf_counter()
        done = subprocess.run(cmd, stdout=subprocess.DEVNULL,
                              stderr=subprocess.DEVNULL if current_settings().quiet else None)
        timings[stage] = round(time.perf_counter() - t0, 1)
        if done.returncode != 0:
            failed.append(stage)
            warn(f"bench {stage} failed with exit status {done.returncode}")
    result, md = summarize(out_dir)
    result.update(failed=failed, seconds=timings)
    emit(result, md + f"\n\nwrote {', '.join(result['files'])}"
          + (f"\nfailed: {', '.join(failed)}" if failed else ""))
    if failed:
        sys.exit(1)
