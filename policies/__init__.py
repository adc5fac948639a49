"""Controllers acting on the environment's observation: scripted baselines and RL baselines."""

from policies.base import ControllerSpec, Policy
from policies.scripted import EigenaxisSlewPolicy, PDPolicy, RandomPolicy, ZeroPolicy

POLICIES = {
    "pd": PDPolicy,
    "eigenaxis": EigenaxisSlewPolicy,
    "random": RandomPolicy,
    "zero": ZeroPolicy,
}
# trained baselines (optional extra ``rl``): imported on demand so that the scripted ones never need SB3
TRAINED_POLICIES = {"sac": "policies.rl:SACPolicy", "ppo": "policies.rl:PPOPolicy"}
DEFAULT_ENV_ID = "startracker/AgileSlew-v0"


def policy_env(policy) -> tuple[str, dict]:
    """(env id, env keyword arguments) a policy acts on: a trained policy's own (``trained_env``), else
    ``AgileSlew-v0`` with no arguments. ``policy`` is a name, a class or an instance."""
    if isinstance(policy, str):
        policy = load_policy(policy)
    trained = getattr(policy, "trained_env", None)
    if trained is None:
        return DEFAULT_ENV_ID, {}
    return trained()


def load_policy(name: str):
    """A policy class by short name (``pd``, ``eigenaxis``, ``random``, ``zero``, ``sac``, ``ppo``) or
    ``module:Class``."""
    if name in POLICIES:
        return POLICIES[name]
    name = TRAINED_POLICIES.get(name, name)
    if ":" in name:
        import importlib

        module, cls = name.split(":", 1)
        try:
            return getattr(importlib.import_module(module), cls)
        except (ImportError, AttributeError) as exc:
            raise ValueError(f"policy {name!r} cannot be loaded: {exc}") from None
    raise ValueError(f"policy must be one of {sorted(POLICIES) + sorted(TRAINED_POLICIES)} or 'module:Class', "
                     f"got {name!r}")


__all__ = ["ControllerSpec", "Policy", "PDPolicy", "EigenaxisSlewPolicy", "RandomPolicy", "ZeroPolicy", "POLICIES", "TRAINED_POLICIES",
           "load_policy", "policy_env"]
