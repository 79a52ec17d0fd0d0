"""Issue 43: the paper's full training budgets on one lent GPU machine, in about nine minutes of wall time.

`benchmarks/gpu_full_budgets.sh` runs this file's stages side by side and packs the results; this file
holds the stages, called through the library (not the `moseg` CLI, which is not installed there):

    python benchmarks/gpu_full_budgets.py prepare     # here, once: copies the data the stages read into gpudata/
    python benchmarks/gpu_full_budgets.py lce --work W --deadline T       # on the GPU
    python benchmarks/gpu_full_budgets.py worker --work W --deadline T --id N --device cpu|auto
    python benchmarks/gpu_full_budgets.py collect --work W --summary FILE --results FILE

1. lce: `moseg study lce-curve --budget full` (the recipe, 64 samples per step, constant learning rate after
   the warm-up) on the GPU. The full budget is 20 000 steps; the stage measures a GPU step and the scoring
   of a clip first and trains as many of the 20 000 steps as end before the deadline (with a constant
   learning rate a shorter run is the same curve, stopped earlier), scored at 5 checkpoints on the first
   100 val and all 200 test samples.
2. losses: the losses study's L2 and MaxInterMinIntra rows (KT3DMoSeg and AdelaideRMF, models from
   scratch, batches of 8) at the full budget's 3000 steps per model, on the cpu budget's two folds (the
   full budget's 22 + 19 leave-one-out folds per loss, 246 000 steps in all, do not fit): 8 models, one per
   CPU worker.
3. loo: `moseg eval kt3d-loo --variant augment --init gpudata/base-f5.pt --steps 1500 --baselines ''`,
   one fold per task, as many of the 22 folds as end before the deadline.

Stages 2 and 3 are tasks of one queue that CPU workers (one thread each) take in order, each only when
its estimated time ends before the deadline; when the LCE stage ends, a GPU worker joins the queue.
Each finished model or fold is written as soon as it ends, so a stage cut off keeps what it had.

Settings (environment): GPU43_TINY=1 shrinks every stage to seconds (the CPU check of the script);
GPU43_LOSS_STEPS (3000), GPU43_LOO_STEPS (1500), GPU43_CPU_STEP_S (0.1: the first guess of a CPU
step of a 12-block model, replaced by each worker's own measurement), GPU43_GPU_STEP_S (0.03),
GPU43_LCE_CHECKPOINTS (5), GPU43_DATA (gpudata/data), GPU43_INIT (gpudata/base-f5.pt).
"""

from __future__ import annotations

import argparse
import json
import logging
import os
import shutil
import time
from dataclasses import asdict, replace
from pathlib import Path
from typing import Any

TINY = os.environ.get("GPU43_TINY", "0") not in ("", "0")
LOSS_STEPS = int(os.environ.get("GPU43_LOSS_STEPS", "4" if TINY else "3000"))
LOO_STEPS = int(os.environ.get("GPU43_LOO_STEPS", "4" if TINY else "1500"))
CPU_STEP_S = float(os.environ.get("GPU43_CPU_STEP_S", "0.1"))
GPU_STEP_S = float(os.environ.get("GPU43_GPU_STEP_S", "0.03"))
LCE_CHECKPOINTS = int(os.environ.get("GPU43_LCE_CHECKPOINTS", "2" if TINY else "5"))
DATA = Path(os.environ.get("GPU43_DATA", "gpudata/data"))
INIT = Path(os.environ.get("GPU43_INIT", "gpudata/base-f5.pt"))
LOSS_ROWS = ("L2 regression", "MaxInterMinIntra")
"""The losses study's rows run here (the labels of studies.training.LOSSES_STUDY)."""
LOO_FOLDS_TINY = 3


def say(msg: str) -> None:
    print(f"[{time.strftime('%H:%M:%S')}] {msg}", flush=True)


def _quiet_logs() -> None:
    logging.basicConfig(level=logging.INFO, format="%(asctime)s %(name)s %(levelname)s %(message)s")
    # Only the first frame of each KT3DMoSeg sequence travels (for the image size): no warning per load.
    logging.getLogger("mosegpipe.data.kt3dmoseg").setLevel(logging.ERROR)
    logging.getLogger("mosegpipe.group.cluster").setLevel(logging.ERROR)


# ---------------------------------------------------------------------------------------------
# prepare (here, before the run): the data the stages read, inside the repository (git-ignored)


def cmd_prepare(args: argparse.Namespace) -> None:
    src, dest = Path(args.data), Path(args.dest) / "data"
    (dest / "kt3dmoseg" / "tracks").mkdir(parents=True, exist_ok=True)
    for p in sorted((src / "kt3dmoseg" / "tracks").glob("*_Tracks.mat")):
        shutil.copy2(p, dest / "kt3dmoseg" / "tracks" / p.name)
    for d in sorted((src / "kt3dmoseg" / "frames").iterdir()):
        first = sorted(d.iterdir())[0]  # the reader needs the frame folder and its first frame (image size)
        (dest / "kt3dmoseg" / "frames" / d.name).mkdir(parents=True, exist_ok=True)
        shutil.copy2(first, dest / "kt3dmoseg" / "frames" / d.name / first.name)
    shutil.copytree(src / "adelaidermf" / "F", dest / "adelaidermf" / "F", dirs_exist_ok=True)
    if not INIT.is_file():
        say(f"missing {INIT}: train it with `moseg train --preset base-f5 --out {INIT} --threads 1`")
    size = sum(p.stat().st_size for p in Path(args.dest).rglob("*") if p.is_file())
    say(f"{args.dest}: {size / 2**20:.1f} MiB")


# ---------------------------------------------------------------------------------------------
# lce: the lce-curve study's full budget on the GPU, as many of its steps as end by the deadline


def cmd_lce(args: argparse.Namespace) -> None:
    _quiet_logs()
    from mosegpipe.runtime import set_threads

    set_threads(1)
    import torch

    from mosegpipe.evaluation.baselines import BASELINES
    from mosegpipe.studies import StudyRequest, get_study
    from mosegpipe.studies import lce as sl
    from mosegpipe.training.loop import TrainConfig, resolve_device, train_model

    work = Path(args.work) / "lce"
    work.mkdir(parents=True, exist_ok=True)
    device = resolve_device("auto")
    name = torch.cuda.get_device_name(0) if device.startswith("cuda") else "cpu"
    say(f"lce: device {device} ({name}), torch {torch.__version__}")
    cc = sl.CURVE_CONFIGS[0]
    cfg = TrainConfig(**{**asdict(cc.train), "steps": sl.FULL_STEPS, "batch_size": sl.FULL_BATCH})
    val, test = (4, 6) if TINY else (100, 200)
    cal = 6 if TINY else 80
    t0 = time.perf_counter()
    res = train_model(sl.train_sampler(), cfg, cc.model, log_every=2, stop_after=cal, device=device)
    hist = res.history
    step_s = (hist[-1]["seconds"] - hist[1]["seconds"]) / (hist[-1]["step"] - hist[1]["step"])
    clips = sl._splits(sl.CurveBudget(num_checkpoints=1, val_clips=1, test_clips=20))["test"]
    t1 = time.perf_counter()
    sl.score_clips(res.model, clips)
    clip_s = (time.perf_counter() - t1) / len(clips)
    t2 = time.perf_counter()
    for c in clips[:5]:
        BASELINES["kmeans-raw"](c.traj, c.k)
    kmeans_s = (time.perf_counter() - t2) / 5 * test
    left = args.deadline - time.time() - (5.0 if TINY else 25.0)
    scoring = LCE_CHECKPOINTS * (val + test) * clip_s * 1.15 + kmeans_s
    steps = int(min(sl.FULL_STEPS, max(2 * LCE_CHECKPOINTS, (left - scoring) / (step_s * 1.1))))
    if TINY:
        steps = min(steps, 20)
    plan = {
        "device": device,
        "device_name": name,
        "torch": torch.__version__,
        "calibration_seconds": round(time.perf_counter() - t0, 1),
        "step_seconds": round(step_s, 5),
        "score_seconds_per_clip": round(clip_s, 4),
        "kmeans_reference_seconds": round(kmeans_s, 1),
        "seconds_left": round(left, 1),
        "steps": steps,
        "full_budget_steps": sl.FULL_STEPS,
        "batch_size": sl.FULL_BATCH,
        "samples": steps * sl.FULL_BATCH,
        "checkpoints": sl.checkpoint_steps(steps, LCE_CHECKPOINTS),
        "expected_seconds": round(steps * step_s + scoring, 1),
    }
    (work / "plan.json").write_text(json.dumps(plan, indent=1))
    say(f"lce plan: {json.dumps(plan)}")
    del res
    budget = sl.CurveBudget(
        num_checkpoints=LCE_CHECKPOINTS,
        val_clips=val,
        test_clips=test,
        full_steps=steps,
        batch_size=sl.FULL_BATCH,
        num_configs=1,
    )
    req = StudyRequest(out_dir=work, budget="full", device=device, progress=say)
    result = sl.run_lce_curve(get_study("lce-curve"), req, budget=budget)
    say(f"lce: done, {result.results['wall_seconds']} s")


# ---------------------------------------------------------------------------------------------
# worker: the losses models and the kt3d-loo folds, one task at a time


def _tasks(root: Path) -> list[dict[str, Any]]:
    from mosegpipe.data.kt3dmoseg import list_kt3d_sequences

    tasks: list[dict[str, Any]] = [
        {"key": f"losses__{d}__{_slug(label)}__{fold}", "kind": "losses", "dataset": d, "label": label, "fold": fold}
        for label in LOSS_ROWS
        for d in ("kt3dmoseg", "adelaidermf")
        for fold in ("even", "odd")
    ]
    names = list_kt3d_sequences(root)
    if TINY:
        names = names[:LOO_FOLDS_TINY]
    tasks += [{"key": f"loo__{n}", "kind": "loo", "fold": n} for n in names]
    return tasks


def _slug(label: str) -> str:
    return "-".join("".join(ch if ch.isalnum() else " " for ch in label.lower()).split())


def _claim(work: Path, key: str) -> bool:
    (work / "claims").mkdir(parents=True, exist_ok=True)
    try:
        fd = os.open(work / "claims" / key, os.O_CREAT | os.O_EXCL | os.O_WRONLY)
    except FileExistsError:
        return False
    os.close(fd)
    return True


def _run_losses(task: dict[str, Any], work: Path, root: Path, device: str, deadline: float) -> dict[str, Any]:
    from mosegpipe.studies.training import (
        LOSSES_STUDY,
        TrainingBudget,
        fold_key,
        load_datasets,
        make_folds,
        scored_clips,
        train_and_score,
    )

    data = load_datasets()[task["dataset"]]
    budget = TrainingBudget(steps=LOSS_STEPS)  # two folds, as the cpu budget
    variant = next(v for v in LOSSES_STUDY.variants if v.label == task["label"])
    clips = scored_clips(data, root, budget)
    held_out = dict(make_folds(clips, data, budget))[task["fold"]]
    test = [c for c in clips if fold_key(c) in held_out]
    # Safety only: a model still training at the deadline stops and is scored ("steps" says how far it got).
    limit = max(10.0, deadline - time.time() - 25.0)
    payload = train_and_score(
        data, variant, LOSS_STEPS, root, held_out, test, seed=0, device=device, time_budget_s=limit
    )
    payload |= {"dataset": task["dataset"], "variant": task["label"], "fold": task["fold"], "trial": 0}
    payload |= {"planned_steps": LOSS_STEPS, "device": device}
    out = work / "losses" / "parts" / f"{task['key']}.json"
    out.parent.mkdir(parents=True, exist_ok=True)
    tmp = out.with_suffix(".tmp")
    tmp.write_text(json.dumps(payload))
    tmp.replace(out)
    return {"steps": payload["steps"], "train_seconds": payload["train_seconds"]}


def _loo_request(out_dir: Path, root: Path, folds: tuple[str, ...], device: str, k_method: str = "silhouette") -> Any:
    from mosegpipe.evaluation.protocols import EvalRequest

    return EvalRequest(
        out_dir=out_dir,
        data_root=root,
        init=INIT,
        variant="augment",
        steps=LOO_STEPS,
        baselines=(),
        folds=folds,
        k_method=k_method,
        device=device,
        progress=say,
    )


def _run_loo(task: dict[str, Any], work: Path, root: Path, device: str, worker: str) -> dict[str, Any]:
    from mosegpipe.evaluation.protocols import get_protocol

    proto = get_protocol("kt3d-loo")
    out_dir = work / "loo" / f"w{worker}"
    t0 = time.perf_counter()
    result = proto.run(proto, _loo_request(out_dir, root, (task["fold"],), device))
    seconds = [r.get("train_seconds") for r in result.rows]
    return {"steps": LOO_STEPS, "train_seconds": seconds[0] if seconds else time.perf_counter() - t0}


def cmd_worker(args: argparse.Namespace) -> None:
    _quiet_logs()
    from mosegpipe.runtime import set_threads

    set_threads(1)
    from mosegpipe.training.loop import resolve_device

    device = resolve_device(args.device)
    work, root = Path(args.work), DATA
    step_s = GPU_STEP_S if device.startswith("cuda") else CPU_STEP_S
    (work / "tasks").mkdir(parents=True, exist_ok=True)
    say(f"worker {args.id}: device {device}, first guess {step_s} s per step")
    for task in _tasks(root):
        steps = LOSS_STEPS if task["kind"] == "losses" else LOO_STEPS
        overhead = 3.0 if TINY else (20.0 if task["kind"] == "losses" else 15.0)
        estimate = steps * step_s + overhead
        if (work / "claims" / task["key"]).exists():
            continue
        if time.time() + estimate > args.deadline:
            say(f"worker {args.id}: {task['key']} would end after the deadline ({estimate:.0f} s): left")
            continue
        if not _claim(work, task["key"]):
            continue
        say(f"worker {args.id}: {task['key']} ({steps} steps, estimated {estimate:.0f} s)")
        t0 = time.time()
        record: dict[str, Any] = {**task, "worker": args.id, "device": device, "started": t0}
        try:
            if task["kind"] == "losses":
                record |= _run_losses(task, work, root, device, args.deadline)
            else:
                record |= _run_loo(task, work, root, device, args.id)
            record["status"] = "done"
        except Exception as exc:  # one failed task must not stop the others; the record says why
            logging.exception("task %s failed", task["key"])
            record["status"] = f"failed: {type(exc).__name__}: {exc}"
        record["seconds"] = round(time.time() - t0, 1)
        (work / "tasks" / f"{task['key']}.json").write_text(json.dumps(record))
        if record["status"] == "done" and record.get("steps"):
            step_s = max(1e-4, float(record["train_seconds"]) / int(record["steps"]))
        say(f"worker {args.id}: {task['key']} {record['status']} in {record['seconds']} s ({step_s:.4f} s per step)")


# ---------------------------------------------------------------------------------------------
# collect: tables and one results.json from whatever the stages finished


def _collect_lce(work: Path) -> tuple[str, dict[str, Any]]:
    lce = work / "lce"
    plan = json.loads((lce / "plan.json").read_text()) if (lce / "plan.json").is_file() else {}
    head = ""
    if plan:
        head = (
            f"Ran {plan['steps']:,} of the full budget's {plan['full_budget_steps']:,} steps of {plan['batch_size']} "
            f"samples ({plan['samples']:,} samples seen; the paper: 2.4 M) on {plan['device_name']}: a step took "
            f"{1000 * plan['step_seconds']:.1f} ms and scoring a clip {1000 * plan['score_seconds_per_clip']:.0f} ms "
            "when measured at the start. With the constant learning rate these checkpoints lie on the full run's "
            "curve. (The budget line below describes the whole full budget.)\n\n"
        )
    if (lce / "results.json").is_file():
        return head + (lce / "table.md").read_text(), {"plan": plan, **json.loads((lce / "results.json").read_text())}
    rows = []
    for p in sorted((lce / "parts").glob("recipe__step*.json")):
        rows.append(json.loads(p.read_text())["payload"])
    rows.sort(key=lambda r: int(r["step"]))
    if not rows:
        return "(the LCE stage scored no checkpoint)\n", {"plan": plan, "rows": []}
    from mosegpipe.studies import lce as sl

    kmeans_part = lce / "parts" / "kmeans-raw.json"
    kmeans = json.loads(kmeans_part.read_text())["payload"]["error_true_k"] if kmeans_part.is_file() else float("nan")
    cc = replace(sl.CURVE_CONFIGS[0], train=replace(sl.CURVE_CONFIGS[0].train, batch_size=sl.FULL_BATCH))
    lines = sl._tables([cc], {cc.name: int(plan.get("steps", rows[-1]["step"]))}, rows, kmeans)
    table = head + "\n".join(["# lce-curve, cut off before the end: the checkpoints it scored", "", *lines, ""])
    return table, {"plan": plan, "rows": rows, "kmeans_raw_true_k": kmeans, "cut_off": True}


def _collect_losses(work: Path, out: Path) -> tuple[str, dict[str, Any]]:
    from mosegpipe.studies import common as st
    from mosegpipe.studies.training import LOSSES_STUDY, plot_summary, summarize_variants, table_text

    parts = [json.loads(p.read_text()) for p in sorted((work / "losses" / "parts").glob("*.json"))]
    if not parts:
        return "(the losses stage finished no model)\n", {"parts": []}
    summary = summarize_variants(parts)
    spec = replace(LOSSES_STUDY, variants=tuple(v for v in LOSSES_STUDY.variants if v.label in LOSS_ROWS))
    done = [f"{p['dataset']}/{p['variant']}/{p['fold']}: {p['steps']} of {p['planned_steps']} steps" for p in parts]
    notes = [
        f"Budget: the cpu budget's two folds (even / odd sequences and pairs held out in turn) at {LOSS_STEPS} steps "
        "of 8 clips per model from scratch (the full budget's step count; its leave-one-out folds do not fit).",
        f"Models finished ({len(parts)} of {2 * 2 * len(LOSS_ROWS)}): " + "; ".join(done) + ".",
        "Error: misclassification rate with the automatic K (silhouette, K <= 8), mean over the test clips; "
        "a dataset whose two folds did not both finish is scored on half its clips (see clips in results.json).",
    ]
    table = table_text(spec, summary, notes)
    req = st.StudyRequest(out_dir=out)
    st.write_outputs(req, table, {"summary": summary, "parts": parts, "steps": LOSS_STEPS}, plot_summary(spec, summary))
    return table, {"summary": summary, "parts": parts}


def _collect_loo(work: Path, out: Path) -> tuple[str, dict[str, Any]]:
    from mosegpipe.evaluation.protocols import get_protocol

    folds = out / "folds"
    folds.mkdir(parents=True, exist_ok=True)
    for p in sorted((work / "loo").glob("w*/folds/*.json")):
        if p.with_suffix(".pt").is_file():
            shutil.copy2(p, folds / p.name)
            shutil.copy2(p.with_suffix(".pt"), folds / p.with_suffix(".pt").name)
    names = tuple(sorted(p.stem for p in folds.glob("*.json")))
    if not names:
        return "(the kt3d-loo stage finished no fold)\n", {"folds": []}
    proto = get_protocol("kt3d-loo")
    tables, results = [], {"folds": list(names), "steps": LOO_STEPS}
    for k_method in ("silhouette", "residual"):
        where = out if k_method == "silhouette" else out / "by-k-method" / k_method
        if where != out:
            shutil.copytree(folds, where / "folds", dirs_exist_ok=True)
        res = proto.run(proto, _loo_request(where, DATA, names, "cpu", k_method))  # re-scores, trains nothing
        tables.append(f"### K rule: {k_method}\n\n{res.table}")
        results[k_method] = res.summary
    head = (
        f"# kt3d-loo, augment, {LOO_STEPS} steps per fold from {INIT}: {len(names)} of 22 folds\n\n"
        f"Held out: {', '.join(names)}\n"
    )
    return head + "\n" + "\n\n".join(tables) + "\n", results


def cmd_collect(args: argparse.Namespace) -> None:
    _quiet_logs()
    from mosegpipe.runtime import set_threads

    set_threads(1)
    work = Path(args.work)
    sections = [f"# Issue 43: full training budgets on the GPU machine{' (TINY check)' if TINY else ''}", ""]
    results: dict[str, Any] = {}
    for name, fn in (
        ("lce", lambda: _collect_lce(work)),
        ("losses", lambda: _collect_losses(work, work / "losses")),
        ("loo", lambda: _collect_loo(work, work / "loo" / "all")),
    ):
        try:
            table, res = fn()
        except Exception as exc:  # a broken stage must not hide the others
            logging.exception("collecting %s failed", name)
            table, res = f"(collecting {name} failed: {type(exc).__name__}: {exc})\n", {"error": str(exc)}
        sections += [f"## {name}", "", table, ""]
        results[name] = res
    tasks = [json.loads(p.read_text()) for p in sorted((work / "tasks").glob("*.json"))]
    results["tasks"] = tasks
    sections += [
        "## tasks",
        "",
        "| task | worker | device | status | steps | train s | wall s |",
        "|---|---|---|---|---|---|---|",
    ]
    sections += [
        f"| {t['key']} | {t['worker']} | {t['device']} | {t['status']} | {t.get('steps', '')} | "
        f"{t.get('train_seconds', '')} | {t['seconds']} |"
        for t in tasks
    ]
    settings = {"tiny": TINY, "loss_steps": LOSS_STEPS, "loo_steps": LOO_STEPS, "lce_checkpoints": LCE_CHECKPOINTS}
    results["settings"] = settings
    Path(args.summary).write_text("\n".join(sections) + "\n")
    Path(args.results).write_text(json.dumps(results, indent=1, default=str))
    say(f"wrote {args.summary} and {args.results}")


def main(argv: list[str] | None = None) -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    sub = parser.add_subparsers(dest="cmd", required=True)
    p = sub.add_parser("prepare")
    p.add_argument("--data", default="../shared/data")
    p.add_argument("--dest", default="gpudata")
    for name in ("lce", "worker"):
        p = sub.add_parser(name)
        p.add_argument("--work", required=True)
        p.add_argument("--deadline", type=float, required=True, help="epoch seconds by which the stage ends")
        if name == "worker":
            p.add_argument("--id", required=True)
            p.add_argument("--device", default="cpu")
    p = sub.add_parser("collect")
    p.add_argument("--work", required=True)
    p.add_argument("--summary", required=True)
    p.add_argument("--results", required=True)
    args = parser.parse_args(argv)
    {"prepare": cmd_prepare, "lce": cmd_lce, "worker": cmd_worker, "collect": cmd_collect}[args.cmd](args)


if __name__ == "__main__":
    main()
