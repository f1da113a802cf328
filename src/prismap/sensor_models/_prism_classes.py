"""A conditioned model's PRISM models as one: their tables in one cache, and a frame's rays of every class in one
look-up.

A conditioned PRISM model (:class:`~prismap.sensor_models.ConditionedModel`) holds a plain model and one per
error class, alike but for the error mixture. Each would keep its own tables within its own budget and take its
own call per class and chunk (hundreds a frame, each with its Python steps). Here they share one
:class:`~prismap.sensor_models._prism_cache.TableCache` (each model's keys offset by its ``_table_tag``, so one
budget and one least-recently-used order hold every class), and rays of any classes go through one key search,
one failure posterior and one look-up kernel call (``_kernels_lookup.prism_table_cells``, the cells in runs of one
class). Every table and every cell's value is the one the class's own model gives.
"""

from __future__ import annotations

import dataclasses

import numpy as np

from prismap.sensor_models._failure import failure_constants, failure_posterior_terms
from prismap.sensor_models._kernel_args import cell_runs, mixture_set
from prismap.sensor_models._kernels_pack import _OFFSET
from prismap.sensor_models._prism import PrismModel
from prismap.sensor_models._prism_cache import KEY_TAG_SPAN, TableCache, ray_tables
from prismap.sensor_models._prism_reach import floor_depths, influence_depths

_SHARED_FIELDS = tuple(
    f.name for f in dataclasses.fields(PrismModel) if f.init and f.name not in ("error_model", "table_memory_mb")
)
"""The parameters the models must share (all but the error mixture; the first model's table budget is the shared
cache's)."""


class PrismClasses:
    """PRISM models (a conditioned model's plain one, then one a class) sharing one table cache, and the fused
    look-up of rays of any of them.

    Parameters
    ----------
    models : sequence of PrismModel
        Model ``i`` takes the rays of index ``i``. Their caches are replaced by one with the first model's budget
        (kept if they already share it, as the memoised :meth:`PrismModel.with_extra_noise` copies of an earlier
        set do).
    """

    def __init__(self, models):
        self.models = tuple(models)
        first = self.models[0]
        shared = all(
            model._cache is first._cache and model._table_tag == i * KEY_TAG_SPAN for i, model in enumerate(self.models)
        )
        cache = first._cache if shared else TableCache(first._cache.budget_bytes, first._cache.floor_bytes)
        for i, model in enumerate(self.models):
            object.__setattr__(model, "_cache", cache)
            object.__setattr__(model, "_table_tag", i * KEY_TAG_SPAN)
        self.cache = cache
        self.mixtures = mixture_set([model._mixture() for model in self.models], [model._ku() for model in self.models])
        fails = {model.error_model.failure_weight > 0 for model in self.models}
        self.failures = None  # per model: failure_constants, (4, K)
        if fails == {True}:
            self.failures = np.array([failure_constants(model.error_model) for model in self.models]).T
        # Rays of several models go through influence_depth and cell_posteriors in one call when the models are
        # alike but for their mixtures, with method "table", prior "p0", and matcher failures in all mixtures or in
        # none; otherwise each model takes its own calls (on the shared cache).
        self.fused = (
            first.method == "table"
            and first.prior == "p0"
            and len(fails) == 1
            and all(getattr(model, name) == getattr(first, name) for model in self.models for name in _SHARED_FIELDS)
        )

    @classmethod
    def of(cls, models):
        """The :class:`PrismClasses` of ``models``, or None unless they are all PRISM models."""
        return cls(models) if all(type(model) is PrismModel for model in models) else None

    def _build(self, keys):
        """The tables of tagged ``keys``, each built by the model of its tag (:meth:`PrismModel._build_tables`), in
        the keys' order: ``nodes`` (a list of arrays read back to back) and ``meta``."""
        index = (keys + KEY_TAG_SPAN // 2) // KEY_TAG_SPAN
        meta, nodes, first = None, [], 0
        for i in np.unique(index):
            mine = np.flatnonzero(index == i)
            part_nodes, part_meta = self.models[i]._build_tables(keys[mine] - i * KEY_TAG_SPAN)
            if meta is None:
                meta = np.empty((keys.size, part_meta.shape[1]))
            part_meta[:, _OFFSET] += first
            meta[mine] = part_meta
            for part in part_nodes if isinstance(part_nodes, list) else [part_nodes]:
                nodes.append(part)
                first += part.shape[0]
        return nodes, meta

    def tables_for(self, disparity, norm, index):
        """:func:`~prismap.sensor_models._prism_cache.ray_tables` of rays of model ``index`` ((R,) int) each, one
        search and one build call for all."""
        tag = np.asarray(index, dtype=np.int64) * KEY_TAG_SPAN
        return ray_tables(self.cache, self._build, disparity, norm, tag, self.models[0].disparity_step_px)

    def influence_depth(self, disparity, norm, index, voxel_overhang_m=None):
        """:meth:`PrismModel.influence_depth` of each ray by its model ``index`` ((R,) int)."""
        terms = self._ray_terms(disparity, norm, index)
        return influence_depths(self.models[0], terms, self.mixtures, norm, voxel_overhang_m)

    def influence_and_floor_depths(self, disparity, norm, index, voxel_overhang_m=None):
        """:meth:`PrismModel.influence_and_floor_depths` of each ray by its model ``index`` ((R,) int)."""
        terms, first = self._ray_terms(disparity, norm, index), self.models[0]
        return (
            influence_depths(first, terms, self.mixtures, norm, voxel_overhang_m),
            floor_depths(first, terms, self.mixtures, norm, voxel_overhang_m),
        )

    def _ray_terms(self, disparity, norm, index):
        """:meth:`PrismModel._ray_terms` of rays of model ``index`` each: tables, ``log Z``, failure terms, ``index``
        as int64."""
        tables = self.tables_for(disparity, norm, index)
        log_z = self.models[0]._ray_log_z(tables)
        index = np.asarray(index, dtype=np.int64)
        return tables, log_z, self._log_failure(log_z, index), index

    def _log_failure(self, log_z, index):
        """:meth:`PrismModel._log_failure` of rays of ``log Z`` ``log_z``, each by its model ``index``."""
        if self.failures is None:
            return np.empty(0), np.empty(0)
        return failure_posterior_terms(*self.failures[:, index], log_z)

    def cell_posteriors(self, disparity_px, ray_norm, ray_of_cell, start, end, index, voxel_overhang_m=None):
        """:meth:`PrismModel.cell_posteriors` of each cell by its ray's model ``index`` ((R,) int), in one look-up
        of the cells in runs of one model (:func:`~prismap.sensor_models._kernel_args.cell_runs`):
        ``(posterior, increment)``, (C,) each."""
        first = self.models[0]
        disparity, norm, rays, start, end, stretch, lam = first._prepared(
            disparity_px, ray_norm, ray_of_cell, start, end, voxel_overhang_m
        )
        tables = self.tables_for(disparity, norm, index)
        log_failure = self._log_failure(first._ray_log_z(tables), index)
        order, runs = cell_runs(np.asarray(index, dtype=np.int64), rays)
        if order is not None:  # the look-up takes runs of one model
            rays, start, end = rays[order], start[order], end[order]
        posterior, increment = first._table_cells(
            lam, rays, start, end, stretch, tables, log_failure, runs, self.mixtures
        )
        if order is not None:
            posterior[order], increment[order] = posterior.copy(), increment.copy()
        return posterior, increment
