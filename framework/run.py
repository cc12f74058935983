"""Command line: ``python -m framework.run method=symbolic scene=urban_canyon`` (Hydra).

A thin entry: the work is :func:`framework.experiment.run_experiment`. A user error prints one
line (``error: ...``) and exits with status 2, leaving no results.json.
"""
from __future__ import annotations

import logging
import shutil
import sys
from pathlib import Path

import hydra
from hydra.core.hydra_config import HydraConfig
from omegaconf import DictConfig, OmegaConf

from framework.errors import UserError

log = logging.getLogger("framework.run")


def scene_label(name, directory) -> str:
    """Run-folder label of a scene: the bundled name, or the folder's name for ``scene.dir``."""
    return Path(str(directory)).name if directory else str(name)


if not OmegaConf.has_resolver("scene_label"):
    OmegaConf.register_new_resolver("scene_label", scene_label)


@hydra.main(version_base=None, config_path="conf", config_name="config")
def main(cfg: DictConfig) -> None:
    run_dir = Path(HydraConfig.get().runtime.output_dir)
    from framework.experiment import run_experiment
    try:
        run_experiment(cfg, run_dir)
    except UserError as exc:
        print(f"error: {exc}", file=sys.stderr)
        log.error("%s", exc)
        if not (run_dir / "results.json").exists():
            shutil.rmtree(run_dir, ignore_errors=True)      # no partial output
        if HydraConfig.get().mode.name == "RUN":
            sys.exit(2)


if __name__ == "__main__":
    main()
