"""Controllers acting on the environment's observation: scripted baselines and an RL baseline."""

from policies.base import ControllerSpec, Policy
from policies.scripted import EigenaxisSlewPolicy, PDPolicy, RandomPolicy, ZeroPolicy

POLICIES = {
    "pd": PDPolicy,
    "eigenaxis": EigenaxisSlewPolicy,
    "random": RandomPolicy,
    "zero": ZeroPolicy,
}


def load_policy(name: str):
    """A policy class by short name (``pd``, ``eigenaxis``, ``random``, ``zero``) or ``module:Class``."""
    if name in POLICIES:
        return POLICIES[name]
    if ":" in name:
        import importlib

        module, cls = name.split(":", 1)
        try:
            return getattr(importlib.import_module(module), cls)
        except (ImportError, AttributeError) as exc:
            raise ValueError(f"policy {name!r} cannot be loaded: {exc}") from None
    raise ValueError(f"policy must be one of {sorted(POLICIES)} or 'module:Class', got {name!r}")


__all__ = ["ControllerSpec", "Policy", "PDPolicy", "EigenaxisSlewPolicy", "RandomPolicy", "ZeroPolicy", "POLICIES", "load_policy"]
