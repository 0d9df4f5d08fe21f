"""Gymnasium's vector observations and infos of a batch (``VSWristVectorEnv``'s mixin): flat rows or dicts of
terms, and infos as arrays with ``_key`` masks, or one dict per world (SB3's adapter)."""

from __future__ import annotations

from typing import Any

import numpy as np


class VectorInfoMixin:
    """Observation and info plumbing of ``VSWristVectorEnv``."""

    def _flat(self, obs) -> np.ndarray:
        """A world's observation as the flat float32 row (a dict observation concatenated in term order)."""
        if self._dict_obs:
            return np.concatenate([obs[name] for name in self._obs_names])
        return obs

    def _unflat(self, flat: np.ndarray):
        """Flat rows (N, obs_size) or one row as the batch's (or a world's) observation."""
        if self._dict_obs:
            return {name: flat[..., sl].copy() for name, sl in self._obs_slices.items()}
        return flat

    def _vector_info(self, cols_, rows: dict, extras: dict) -> dict:
        """Gymnasium's vector info: each key an array over worlds, with a bool mask ``_key`` of the worlds that
        have it."""
        idx, cols = cols_
        n = self.num_envs
        if not cols and not extras and len(rows) == n:  # world by world: stack the worlds' dicts
            return self._merge_infos([rows[i] for i in range(n)])
        out: dict[str, Any] = {}
        if cols and not rows and len(idx) == n:  # every world stepped, none reset: the columns are whole already
            for key, v in cols.items():
                out[key] = v.copy()  # each key its own array, as below
                out[f"_{key}"] = np.ones(n, dtype=bool)
        elif cols:
            mask = np.zeros(n, dtype=bool)
            mask[idx] = True
            if rows:
                mask[list(rows)] = False
            for key, v in (cols.items() if mask.any() else ()):
                full = np.zeros((n,) + v.shape[1:], dtype=v.dtype)
                full[idx] = v
                if rows:
                    full[list(rows)] = 0  # as Gymnasium's vector info leaves the worlds without the key
                out[key] = full
                out[f"_{key}"] = mask.copy()
        for i in sorted(rows):
            out = self._add_info(out, rows[i], i)
        for i in sorted(extras):
            out = self._add_info(out, extras[i], i)
        return out

    def _merge_infos(self, infos: list[dict], mask: np.ndarray | None = None) -> dict:
        """Gymnasium's vector info: each key an array over worlds, with a bool mask ``_key`` of the worlds that
        have it. Keys every world has (the common case) are stacked at once; the rest go through ``_add_info``."""
        out: dict[str, Any] = {}
        n = self.num_envs
        present = [i for i in range(n) if mask is None or mask[i]]
        if not present:
            return out
        keys0 = infos[present[0]].keys()
        uniform = all(infos[i].keys() == keys0 for i in present)
        stacked: set = set()
        if len(present) == n:
            common = set(keys0)
            if not uniform:
                for i in present[1:]:
                    common &= infos[i].keys()
            for k in keys0:
                if k not in common or k in ("final_obs", "final_info"):
                    continue
                vals = [d[k] for d in infos]
                v0 = vals[0]
                if isinstance(v0, (bool, np.bool_)):
                    out[k] = np.array(vals, dtype=bool)
                elif isinstance(v0, (int, float, np.number)):
                    out[k] = np.array(vals, dtype=type(v0))
                elif isinstance(v0, np.ndarray):
                    out[k] = np.stack(vals)
                else:
                    continue
                out[f"_{k}"] = np.ones(n, dtype=bool)
                stacked.add(k)
        if uniform and len(stacked) == len(keys0):
            return out
        for i in present:
            rest = {k: v for k, v in infos[i].items() if k not in stacked}
            if rest:
                out = self._add_info(out, rest, i)
        return out

    def _world_infos(self, cols_, rows: dict, extras: dict) -> list[dict]:
        """The infos as one dict per world, as the single env returns them (for SB3's adapter)."""
        idx, cols = cols_
        infos: list[dict] = [{} for _ in range(self.num_envs)]
        if cols:
            keys = list(cols)
            values = [v.tolist() if v.ndim == 1 else list(v) for v in cols.values()]
            for i, vals in zip(idx, zip(*values)):
                infos[i] = dict(zip(keys, vals))
        for i, extra in extras.items():
            infos[i].update(extra)
        for i, info in rows.items():
            infos[i] = info
        return infos
