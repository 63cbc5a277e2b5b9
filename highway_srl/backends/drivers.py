"""The backend-agnostic IDM ego driver now lives with the other one in sim/policies.py; this name stays for
the callers that import it from here."""

from highway_srl.sim.policies import idm_ego_backend

__all__ = ["idm_ego_backend"]
