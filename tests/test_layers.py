"""The floors of the code (docs/design.md): the contracts `lint-imports` checks (pyproject.toml) cover
every module of the core, so a new module cannot slip out of them."""

import pkgutil
from pathlib import Path

import tomllib

import gpl_dist

ROOT = Path(__file__).resolve().parents[1]


def _contracts() -> dict[str, dict]:
    config = tomllib.loads((ROOT / "pyproject.toml").read_text())["tool"]["importlinter"]
    return {c["name"]: c for c in config["contracts"]}


def test_the_core_contract_names_every_module_of_gpl_dist_but_the_app_layer_and_the_cli():
    core = set(_contracts()["the core imports nothing above it"]["source_modules"])
    children = {f"gpl_dist.{m.name}" for m in pkgutil.iter_modules(gpl_dist.__path__)}
    assert children - core == {"gpl_dist.app", "gpl_dist.cli"}
    assert core <= children  # no stale names


def test_ray_is_allowed_only_in_the_named_wiring_modules_and_those_modules_exist():
    ray = _contracts()["Ray only in the wiring: the Ray collector, the remote learners, Ray Train, the suite's two Ray runners"]
    wiring = {rule.split(" -> ")[0] for rule in ray["ignore_imports"]}
    assert wiring == {"workers.ray_collector", "learner.remote", "learner.ray_train", "gpl_dist.app.suite.cluster",
                      "gpl_dist.app.suite.rl.cluster"}
    for module in wiring:
        assert (ROOT / (module.replace(".", "/") + ".py")).is_file()
