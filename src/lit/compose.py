"""A Hydra config composed in-process as `python -m src.<name>` would (report, notebooks, tests)."""

from __future__ import annotations

from pathlib import Path

from hydra import compose, initialize_config_dir
from hydra.core.global_hydra import GlobalHydra
from hydra.core.hydra_config import HydraConfig
from omegaconf import DictConfig, open_dict

from src.lit.factory import PROJECT_ROOT
from src.lit.run_folders import register_resolvers

CONF_DIR = PROJECT_ROOT / "conf"


def compose_config(
    config_name: str,
    overrides: list[str],
    output_dir: str | Path,
    data_dir: str | Path | None = None,
) -> DictConfig:
    """The config of `conf/<config_name>.yaml` with `overrides`, run folder `output_dir`; sets
    Hydra's global state so that `${hydra:...}` interpolations resolve, as in a real run."""
    register_resolvers()
    GlobalHydra.instance().clear()
    extra = [] if data_dir is None else [f"paths.data_dir={data_dir}"]
    overrides = [f"paths.log_dir={output_dir}", *extra, *overrides]
    with initialize_config_dir(config_dir=str(CONF_DIR), version_base="1.3"):
        cfg = compose(config_name, overrides=overrides, return_hydra_config=True)
    with open_dict(cfg):
        cfg.hydra.runtime.output_dir = str(output_dir)
        cfg.hydra.job.num = 0
    HydraConfig().set_config(cfg)
    return cfg
