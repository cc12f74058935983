"""Command line: ``python -m framework.run method=symbolic scene=urban_canyon`` (Hydra).

A thin entry: the work is :func:`framework.experiment.run_experiment`, the run report
:func:`reports.write_run_report`. A user error prints one line (``error: ...``) and exits with
status 2, leaving no results.json. Every override is listed in ``docs/cli.md``.
"""
from __future__ import annotations

import logging
import shutil
import sys
from pathlib import Path

import hydra
from hydra.core.hydra_config import HydraConfig
from omegaconf import DictConfig

import framework.config  # noqa: F401  (registers the resolvers the configuration uses)
from framework.errors import UserError
from framework.experiment import run_experiment
from reports import write_run_report

log = logging.getLogger("framework.run")


@hydra.main(version_base=None, config_path="conf", config_name="config")
def main(cfg: DictConfig) -> None:
    run_dir = Path(HydraConfig.get().runtime.output_dir)
    try:
        run_experiment(cfg, run_dir, write_report=write_run_report if cfg.get("report", True) else None)
    except UserError as exc:
        print(f"error: {exc}", file=sys.stderr)
        log.error("%s", exc)
        if not (run_dir / "results.json").exists():
            shutil.rmtree(run_dir, ignore_errors=True)      # no partial output
        if HydraConfig.get().mode.name == "RUN":
            sys.exit(2)


if __name__ == "__main__":
    main()
