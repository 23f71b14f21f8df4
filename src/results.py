"""src.eval's work: a baseline, a trained checkpoint or a file of predictions (src/scoring.py),
tested as a MotionPredictor, and its result tables in the papers' layout: an action is evaluated
or absent with its reason (printed "absent", never 0 or NaN); the average is over the evaluated
actions (protocol §4.1 step 6), beside it the published one over the same actions, below it the
paper's own over all of its actions. Where an evaluated action has no training files, a second
average leaves it out (the set src.report's verdict judges), and each row names its set."""

import json
import math
import time
from pathlib import Path

import lightning as L
import pandas as pd
from omegaconf import DictConfig, OmegaConf

from src.build import build_module, build_test_data, load_trained
from src.cli import git_commit, training_run_name
from src.config import ConfigError, check, instantiate
from src.data.files import atomic_write
from src.metrics.averages import averages
from src.metrics.euler_error import horizon_frame_indices
from src.reporting.published import ReportingError, published_for
from src.reporting.tables import AVERAGE, LONG, fmt, markdown, same_set_average
from src.scoring import score_predictions

AVERAGE_TRAINED = "average_trained"  # over the evaluated actions with training files
AS_PRINTED = "average_as_printed"


def results_from_metric(values, actions, frame_ms: float = 40, absent=None) -> dict:
    """{action: {ms: value}} of a metric's (A, T) output; a NaN action must be listed absent."""
    absent, out = dict(absent or {}), {}
    horizons = horizon_frame_indices(frame_ms, values.shape[1])
    for action, row in zip(actions, values.detach().double().cpu().tolist(), strict=True):
        if any(math.isnan(v) for v in row) != (action in absent):
            raise ReportingError(
                f"action {action!r} is listed as absent ({absent[action]}) but has values"
                if action in absent
                else f"action {action!r} has no evaluated windows (NaN); pass it in absent with "
                "the reason (e.g. which data files are missing)"
            )
        if action not in absent:
            out[action] = {ms: row[k] for ms, k in horizons.items()}
    return out


def result_table(
    title,
    metric,
    unit,
    actions,
    horizons_ms,
    values,
    absent,
    published=None,
    published_label=None,
    untrained=(),
) -> dict:
    """The table as results.json holds it; values and absent as results_from_metric gives them;
    `untrained`: the actions without training files (the model's, or this copy's)."""
    horizons = [int(ms) for ms in horizons_ms]
    if not horizons:
        raise ReportingError(f"{title}: no horizons; the model predicts too few frames")
    evaluated, pub = [a for a in actions if a in values], published is not None
    text = lambda row: {str(ms): float(v) for ms, v in row.items()}  # noqa: E731

    def mean(over: list[str]) -> dict:
        return {ms: sum(values[a][ms] for a in over) / len(over) for ms in horizons}

    # results.json's earlier keys unchanged (older readers); the second average has its own.
    trained = averages(evaluated, untrained).get(AVERAGE_TRAINED, (None,))[0]
    if trained:
        same = text(same_set_average(published, trained, horizons)) if pub else None
        trained = {"actions": trained, "values": text(mean(trained)), "published_same_set": same}
    return {
        "title": title,
        "metric": metric,
        "unit": unit,
        "decimals": 1 if unit == "mm" else 2,
        "actions": list(actions),
        "horizons_ms": horizons,
        "values": {a: text(values[a]) for a in evaluated},
        "absent": dict(absent),
        "average": {"actions": evaluated, "values": text(mean(evaluated))} if evaluated else None,
        "published": {a: text(r) for a, r in published.items()} if pub else None,
        "published_label": published_label if pub else None,
        "published_same_set": text(same_set_average(published, evaluated, horizons))
        if pub
        else None,
        "untrained_actions": [a for a in actions if a in untrained],
        AVERAGE_TRAINED: trained,
    }


def table_frame(table: dict) -> pd.DataFrame:
    """Long (action, ms, value, published, note), with the averages same-set and as printed."""
    published, horizons = table.get("published") or {}, list(map(str, table["horizons_ms"]))
    rows = [
        (a, ms, table["values"].get(a, {}).get(ms, "absent"), published.get(a, {}).get(ms))
        + (table["absent"].get(a, ""),)
        for a in table["actions"]
        for ms in horizons
    ]
    if table["average"]:
        covered, same = table["average"]["actions"], table.get("published_same_set") or {}
        note = f"mean over the {len(covered)} evaluated actions ({', '.join(covered)})"
        rows += [
            (AVERAGE, ms, v, same.get(ms), note) for ms, v in table["average"]["values"].items()
        ]
        if trained := table.get(AVERAGE_TRAINED):
            same = trained["published_same_set"] or {}
            note = f"mean over the {len(trained['actions'])} evaluated actions with training "
            note += f"files ({', '.join(trained['actions'])})"
            rows += [
                (AVERAGE_TRAINED, ms, v, same.get(ms), note) for ms, v in trained["values"].items()
            ]
        n = len(set(published) - {AVERAGE})
        scope = f"the paper's own average, over all {n or 'of its'} actions"
        printed = published.get(AVERAGE, {})
        rows += [(AS_PRINTED, ms, "", printed[ms], scope) for ms in horizons if ms in printed]
    frame = pd.DataFrame(rows, columns=["action", "ms", "value", "published", "note"])
    return frame.assign(ms=frame.ms.astype(int), metric=table["metric"])


def table_markdown(table: dict) -> str:
    """results.md's table: ours (published) per cell, absent actions with a footnote."""
    frame, decimals = table_frame(table), table.get("decimals", 2)
    has_published = table.get("published") is not None
    reasons = list(dict.fromkeys(table["absent"].values()))
    names = {AVERAGE: f"**{AVERAGE}**", AS_PRINTED: "published average, as printed"}
    average, untrained = table["average"], table.get("untrained_actions", [])
    sets = averages(average["actions"], untrained) if average else {}
    # With two averages, each row names its set.
    names |= {n: f"**{AVERAGE} ({words})**" for n, (_, words) in sets.items() if words}
    names |= {a: f"{a} [{reasons.index(r) + 1}]" for a, r in table["absent"].items()}

    # A cell: ours (published), "absent", or the paper's own average alone (value "").
    paper = frame.published.map(lambda v: fmt(v, decimals))
    ours = frame.value.map(lambda v: v if isinstance(v, str) else f"{v:.{decimals}f}")
    mixed = ours + " (" + paper + ")" if has_published else ours
    cells = mixed.where(~frame.value.isin(["absent", ""]), ours.where(ours != "", paper))
    frame = frame.assign(cell=cells, action=frame.action.map(lambda a: names.get(a, a)))
    # The paper's own average has no cell where it printed no number (560 ms): '-'.
    wide = frame.pivot(index="action", columns="ms", values="cell").fillna("-")
    wide = wide.reindex(list(dict.fromkeys(frame.action))).rename(columns=lambda ms: f"{ms} ms")
    lines = [f"**{table['title']}** ({table['unit']})", ""]
    lines += [markdown(wide.reset_index()), ""]
    if has_published:
        lines.append(
            f"- Cells: ours (published: {table.get('published_label') or 'published'}); '-' "
            "where the paper has no number. Beside our average: the paper's values averaged "
            "over the same evaluated actions, like for like."
        )
    lines.append(
        f"- Average: mean over the {len(average['actions'])} evaluated actions "
        f"({', '.join(average['actions'])})."
        if average
        else "- Average: no action was evaluated, so there is no average."
    )
    if AVERAGE_TRAINED in sets:
        trained, words = sets[AVERAGE_TRAINED]
        lines.append(
            f"- Average ({words}): mean over the evaluated actions with training files "
            f"({', '.join(trained)}), the set src.report's verdict judges "
            f"({', '.join(untrained)}: no training files)."
        )
    for k, reason in enumerate(reasons, 1):
        who = [a for a in table["actions"] if table["absent"].get(a) == reason]
        lines.append(f"- [{k}] absent ({', '.join(who)}): {reason}")
    return "\n".join(lines) + "\n"


def long_rows(tables, **keys) -> pd.DataFrame:
    """The tables' values as LONG rows, `keys` (run, experiment, ...) the same in each."""
    rows = [
        (t["metric"], a, int(ms), t["values"].get(a, {}).get(str(ms), math.nan))
        + (t["absent"].get(a, ""),)
        for t in tables
        for a in t["actions"]
        for ms in t["horizons_ms"]
    ]
    return pd.DataFrame(rows, columns=LONG[7:]).assign(**dict.fromkeys(LONG[:7]) | keys)[LONG]


def tables_csv(tables) -> str:
    frame = pd.concat([table_frame(t) for t in tables])
    return frame[["metric", "action", "ms", "value", "published", "note"]].to_csv(index=False)


def build_tables(module, dm, model_cfg: dict, dataset: str) -> list[dict]:
    """The Euler and MPJPE tables of an evaluation on `dataset` (the data config's name:
    published numbers stand only beside results on their own dataset, never on "synthetic")."""
    published, label = published_for(model_cfg.get("published"), dataset)
    where = f"{model_cfg['name']} on {dataset} ({dm.eval_protocol} protocol, "
    where += f"{len(dm.eval_windows)} windows)"
    mm = "mm" if dm.dataset_name == "h36m" else "skeleton units"
    tables = []
    for metric, title, unit in (
        ("euler", "Euler-angle error", "rad"),
        ("mpjpe", "Mean per-joint position error", mm),
    ):
        values = results_from_metric(
            module.last_results[metric], dm.actions, dm.frame_ms, dm.absent_actions
        )
        paper = (published, label) if metric == "euler" else (None, None)
        args = (dm.actions, module.horizons, values, dm.absent_actions, *paper)
        # The model's untrained actions (its checkpoint's), a baseline's: this copy's.
        untrained = module.untrained_actions
        tables.append(result_table(f"{title}: {where}", metric, unit, *args, untrained=untrained))
    return tables


def build_for_evaluation(cfg: DictConfig):
    """(test windows' datamodule, module) of src.eval and src.visualize: the trained model of
    `cfg.ckpt_path` on its own data config, or the baseline `cfg.model` on `cfg.data`."""
    if cfg.ckpt_path:
        module = load_trained(cfg.ckpt_path, cfg)
        data_cfg = OmegaConf.create(module.run_info["config"]["data"])
        # Where data lives, and whether its copy lacks files, are facts of this machine.
        for key in ("data_dir", "archive_dir", "allow_partial"):
            data_cfg[key] = cfg.paths[key]
        if cfg.get("data") is not None:  # evaluation settings (protocol, windows) may differ
            for key in ("eval_protocol", "eval_windows_per_action", "eval_stride", "allow_partial"):
                data_cfg[key] = cfg.data[key]
        return build_test_data(cfg, data_cfg, module.normalizer), module
    if cfg.get("model") is None or cfg.get("data") is None:
        raise ConfigError(
            "say what to evaluate: a baseline with model=zero_velocity|running_avg_2|"
            "running_avg_4 and data=h36m|cmu, or a trained model with ckpt_path=..."
        )
    dm = build_test_data(cfg)
    config = {key: OmegaConf.to_container(cfg[key], resolve=True) for key in ("model", "data")}
    module = build_module(cfg, dm, run_info={"commit": git_commit(), "config": config})
    if module.trainable:
        raise ConfigError(
            f"model={cfg.model.name} is a trainable network and no ckpt_path was given; the "
            "numbers of an untrained network mean nothing. Train it with `python -m src.train "
            f"model={cfg.model.name} ...` and pass ckpt_path=<its checkpoint>."
        )
    return dm, module.eval()


def evaluate(cfg: DictConfig) -> dict:
    check(cfg, "eval")
    L.seed_everything(cfg.seed, workers=True)
    start = time.perf_counter()
    dm, module = (score_predictions if cfg.get("predictions") else build_for_evaluation)(cfg)
    model_cfg = module.run_info["config"]["model"]
    dataset = module.run_info["config"]["data"]["name"]
    trainer = instantiate(
        cfg.trainer, logger=False, callbacks=[], enable_checkpointing=False, max_epochs=1
    )
    trainer.test(module, datamodule=dm, verbose=False)
    tables = build_tables(module, dm, model_cfg, dataset)
    out_dir = Path(cfg.paths.output_dir)
    out_dir.mkdir(parents=True, exist_ok=True)
    run_name = training_run_name(cfg.ckpt_path) if cfg.ckpt_path else model_cfg["name"]
    provenance = {
        "model": model_cfg["name"],
        "run_name": run_name,
        "dataset": dataset,
        "checkpoint": str(cfg.ckpt_path) if cfg.ckpt_path else None,
        "predictions": str(cfg.predictions) if cfg.get("predictions") else None,
        "eval_protocol": dm.eval_protocol,
        "windows": len(dm.eval_windows),
        "missing_files": list(dm.missing_files),
        "commit": git_commit(),
        "wall_time_s": round(time.perf_counter() - start, 1),
        "published": model_cfg.get("published"),  # the reference src.report judges against
    }
    markdown = "\n\n".join(table_markdown(t) for t in tables)
    (out_dir / "results.md").write_text(markdown + "\n")
    (out_dir / "results.csv").write_text(tables_csv(tables))
    ckpt = Path(cfg.ckpt_path) if cfg.ckpt_path else None
    keys = {"run": str(ckpt.parent.parent) if ckpt else run_name, "experiment": run_name}
    keys |= {"dataset": dataset, "protocol": dm.eval_protocol, "checkpoint": "-"}
    # A checkpoint's seed is its data config's (the run's `seed`), its iterations the Trainer's.
    if ckpt:
        keys |= {"seed": module.run_info["config"]["data"].get("seed")}
        keys |= {"iterations": module.iterations, "checkpoint": ckpt.name}
    long_rows(tables, **keys).to_csv(out_dir / "results_long.csv", index=False)
    result = {"provenance": provenance, "tables": tables}
    # Last and whole or not at all: its presence marks the folder complete (src/eval.py's
    # started=), which a Ctrl-C or a refusal leaves in place.
    atomic_write(out_dir / "results.json", lambda tmp: tmp.write_text(json.dumps(result, indent=2)))
    print(f"{markdown}\n\nwritten to {out_dir}")
    return result
