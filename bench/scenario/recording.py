"""rerun recordings of scenario runs: one ``.rrd`` per run, and a reader that loads one back.

A :class:`Recording` wraps a ``rerun.RecordingStream`` that writes to a file (to a temporary name first, renamed into
place by :meth:`Recording.close`, so an interrupted run leaves no half-written recording under the final name). Its
methods take the bench's own conventions and do the conversion to rerun in one place:

* transforms are ``T_world_x`` 4 x 4 matrices (m), logged as ``Transform3D`` on the entity (children inherit them);
* cameras use OpenCV's optical frame (x right, y down, z forward): ``Pinhole(camera_xyz=RDF)`` with the pinhole
  ``K`` and the resolution, so the frustum and the image sit where the camera looked;
* images are the dataset's PNG files (``EncodedImage``: the recording stays small), keypoints ``Points2D`` on them;
* point sets take a boolean ``inliers`` mask (green inliers, red outliers);
* numbers that vary over a sweep axis or a view index go on a named sequence timeline (``Scalars``).

* meshes are :class:`~bench.scenario.scene_meshes.MeshPart` (the simulator's own geometry), logged once per body;
  a body's pose per configuration is a ``Transform3D`` on its entity (:meth:`Recording.bodies`);
* every kind sends a **blueprint** (:meth:`Recording.blueprint`): the layout the viewer opens on, so that a recording
  shows the question it answers first (see ``docs/inspection.md``).

Open the file with ``rerun runs/<run>/recording.rrd`` (the viewer ships with rerun-sdk). :func:`load_entities` reads
a recording back with rerun's own reader (``rerun.chunk.RrdReader``) as ``{entity: {component: [values]}}`` - the
tests use it to check what a run logged; :func:`load_blueprint` reads the blueprint's views back.
"""

from __future__ import annotations

import os
from pathlib import Path

import numpy as np

GREEN = (40, 200, 60)
RED = (230, 40, 40)
GREY = (170, 170, 170)


class Recording:
    """A rerun recording written to ``path`` (see the module docstring).

    Parameters
    ----------
    path : path-like
        The ``.rrd`` file to write (its folder is created).
    application_id : str
        rerun application id (the scenario name).
    recording_id : str
        Identifies the run (e.g. ``"<scenario>-seed<N>"``).
    name : str, optional
        The recording's readable name, shown by the viewer in its recordings list and selection panel (e.g.
        ``"in_situ: <scenario>, seed 2"``; :func:`run_name`); default ``recording_id``.
    world : {"z_up", "opencv"}
        Axes of ``world``: z up (a site, MuJoCo's world) or OpenCV's x right, y down, z forward (the x-y table).
    """

    def __init__(self, path, application_id: str, recording_id: str, world: str = "z_up", name: str | None = None):
        import rerun as rr

        self.rr = rr
        self.path = Path(path)
        self.path.parent.mkdir(parents=True, exist_ok=True)
        self._tmp = self.path.with_name(f".{self.path.name}.{os.getpid()}.tmp")
        self.stream = rr.RecordingStream(application_id, recording_id=recording_id)
        self.stream.save(str(self._tmp))
        self.stream.send_recording_name(name or recording_id)
        coords = {"z_up": rr.ViewCoordinates.RIGHT_HAND_Z_UP, "opencv": rr.ViewCoordinates.RDF}
        if world not in coords:
            raise ValueError(f"world: expected one of {', '.join(coords)}, got {world!r}")
        self.stream.log("world", coords[world], static=True)

    # --- time ---------------------------------------------------------------------------------------------------------
    def set_time(self, timeline: str, value: int | float) -> None:
        """Subsequent non-static logs happen at ``value`` on the sequence timeline ``timeline``."""
        self.stream.set_time(timeline, sequence=int(value))

    # --- geometry -----------------------------------------------------------------------------------------------------
    def frame(self, entity: str, T_world_x, axis_length: float = 0.1, static: bool = False) -> None:
        """Pose of a frame (4 x 4, m) with its axes drawn ``axis_length`` long."""
        T = np.asarray(T_world_x, dtype=float)
        self.stream.log(entity, self.rr.Transform3D(translation=T[:3, 3], mat3x3=T[:3, :3]),
                        self.rr.TransformAxes3D(axis_length), static=static)

    def camera(self, entity: str, T_world_cam, K, size, image_png=None, keypoints_uv=None, static: bool = False,
               plane_distance: float = 0.15) -> None:
        """A camera (OpenCV optical frame) at ``T_world_cam`` with intrinsics ``K`` (3 x 3) and ``size`` (w, h).

        ``image_png``: path of the image it took (shown in the frustum); ``keypoints_uv (N, 2)``: points on it (px).
        """
        T = np.asarray(T_world_cam, dtype=float)
        rr = self.rr
        self.stream.log(entity, rr.Transform3D(translation=T[:3, 3], mat3x3=T[:3, :3]), static=static)
        self.stream.log(entity, rr.Pinhole(image_from_camera=np.asarray(K, dtype=float), resolution=list(size),
                                           camera_xyz=rr.ViewCoordinates.RDF, image_plane_distance=plane_distance),
                        static=static)
        if image_png is not None:
            self.stream.log(f"{entity}/image", rr.EncodedImage(path=str(image_png)), static=static)
        if keypoints_uv is not None and len(keypoints_uv):
            self.stream.log(f"{entity}/image/keypoints", rr.Points2D(np.asarray(keypoints_uv, dtype=float), radii=1.5,
                                                                     colors=[GREEN]), static=static)

    def points(self, entity: str, p, inliers=None, color=GREY, radius: float = 0.004, static: bool = False) -> None:
        """3D points ``p (N, 3)`` (m); with a boolean ``inliers`` mask, inliers green and outliers red."""
        p = np.asarray(p, dtype=float).reshape(-1, 3)
        if inliers is None:
            colors = [color] * len(p)
        else:
            colors = np.where(np.asarray(inliers, dtype=bool)[:, None], GREEN, RED).astype(np.uint8)
        self.stream.log(entity, self.rr.Points3D(p, colors=colors, radii=radius), static=static)

    def lines(self, entity: str, strips, color=GREY, radius: float = 0.006, static: bool = False) -> None:
        """Polylines: a list of ``(k, 3)`` arrays (m)."""
        self.stream.log(entity, self.rr.LineStrips3D([np.asarray(s, dtype=float) for s in strips], colors=[color],
                                                     radii=radius), static=static)

    def arrows(self, entity: str, origins, vectors, color=GREY, radius: float = 0.003, static: bool = False) -> None:
        """3D arrows ``vectors (N, 3)`` from ``origins (N, 3)`` (m)."""
        self.stream.log(entity, self.rr.Arrows3D(origins=np.asarray(origins, float).reshape(-1, 3),
                                                 vectors=np.asarray(vectors, float).reshape(-1, 3), colors=[color],
                                                 radii=radius), static=static)

    def ellipsoid(self, entity: str, centre, cov, n_sigma: float = 1.0, color=GREY, static: bool = False) -> None:
        """The ``n_sigma`` ellipsoid of a 3 x 3 covariance ``cov`` (m^2) centred at ``centre`` (m), wireframe."""
        w, V = np.linalg.eigh(0.5 * (np.asarray(cov, float) + np.asarray(cov, float).T))
        if np.linalg.det(V) < 0:
            V[:, 0] = -V[:, 0]
        from bench.geometry.quaternion import matrix_to_quaternion

        q = matrix_to_quaternion(V)  # (w, x, y, z)
        self.stream.log(entity, self.rr.Ellipsoids3D(
            centers=[np.asarray(centre, float)], half_sizes=[n_sigma * np.sqrt(np.clip(w, 0, None))],
            quaternions=[self.rr.Quaternion(xyzw=[q[1], q[2], q[3], q[0]])], colors=[color],
            fill_mode=self.rr.components.FillMode.MajorWireframe, line_radii=0.0015), static=static)

    def points2d(self, entity: str, uv, colors=GREEN, radius: float = 2.0, static: bool = False) -> None:
        """Pixels ``uv (N, 2)`` on an image; ``colors`` one RGB or ``(N, 3)``."""
        c = np.asarray(colors, dtype=np.uint8)
        self.stream.log(entity, self.rr.Points2D(np.asarray(uv, float).reshape(-1, 2), radii=radius,
                                                 colors=c if c.ndim == 2 else [c]), static=static)

    def arrows2d(self, entity: str, origins_uv, vectors_uv, color=GREEN, radius: float = 0.8,
                 static: bool = False) -> None:
        """2D arrows ``vectors_uv (N, 2)`` (px) from ``origins_uv (N, 2)`` on an image."""
        self.stream.log(entity, self.rr.Arrows2D(origins=np.asarray(origins_uv, float).reshape(-1, 2),
                                                 vectors=np.asarray(vectors_uv, float).reshape(-1, 2), colors=[color],
                                                 radii=radius), static=static)

    # --- meshes -------------------------------------------------------------------------------------------------------
    def mesh(self, entity: str, part, albedo=None, static: bool = True) -> None:
        """One :class:`~bench.scenario.scene_meshes.MeshPart` (in the entity's frame); ``albedo`` RGBA tints it."""
        rr = self.rr
        kw = {}
        if part.texture is not None:
            kw.update(vertex_texcoords=part.texcoords, albedo_texture=part.texture)
        elif part.colors is not None:
            kw["vertex_colors"] = part.colors if albedo is None else np.tile(np.asarray(albedo, np.uint8),
                                                                             (len(part.vertices), 1))
        self.stream.log(entity, rr.Mesh3D(vertex_positions=part.vertices, vertex_normals=part.normals,
                                          triangle_indices=np.arange(len(part.vertices), dtype=np.uint32).reshape(-1,
                                                                                                                 3),
                                          **kw), static=static)

    def bodies(self, prefix: str, scene, T_world_model=None, qpos: dict | None = None, meshes: bool = True,
               albedo=None, static: bool = False) -> None:
        """The bodies of a :class:`~bench.scenario.scene_meshes.SceneMeshes` under ``prefix/<body>``.

        Poses ``T_world_model @ T_model_body`` at joint angles ``qpos`` (``{joint: rad}``) on each body entity (at the
        current time unless ``static``); with ``meshes`` the parts too (static, ``prefix/<body>/<part>``).
        """
        T0 = np.eye(4) if T_world_model is None else np.asarray(T_world_model, float)
        for body, T in scene.body_poses(qpos).items():
            T = T0 @ T
            self.stream.log(f"{prefix}/{body}", self.rr.Transform3D(translation=T[:3, 3], mat3x3=T[:3, :3]),
                            static=static)
            if meshes:
                for part in scene.parts[body]:
                    self.mesh(f"{prefix}/{body}/{part.name}", part, albedo=albedo)

    def instances(self, entity: str, T_world_instances) -> None:
        """Draw the content of ``entity`` (e.g. a mesh) once per pose ``T_world_instances (N, 4, 4)`` (static;
        rerun's ``InstancePoses3D``: the mesh is stored once)."""
        T = np.asarray(T_world_instances, float).reshape(-1, 4, 4)
        self.stream.log(entity, self.rr.InstancePoses3D(translations=T[:, :3, 3], mat3x3=T[:, :3, :3]), static=True)

    def blueprint(self, blueprint) -> None:
        """Send the layout the viewer opens on (a ``rerun.blueprint.Blueprint``), made active and default."""
        self.stream.send_blueprint(blueprint, make_active=True, make_default=True)

    # --- numbers and text ---------------------------------------------------------------------------------------------
    def scalar(self, entity: str, value: float) -> None:
        """A number at the current time (set :meth:`set_time` first); NaN is logged as a gap."""
        self.stream.log(entity, self.rr.Scalars(float(value)))

    def text(self, entity: str, markdown: str) -> None:
        """A static markdown note (e.g. the run's summary)."""
        self.stream.log(entity, self.rr.TextDocument(markdown, media_type=self.rr.MediaType.MARKDOWN), static=True)

    def close(self) -> Path:
        """Flush, close and move the file to its final name; returns the path."""
        self.stream.flush()
        self.stream.disconnect()
        os.replace(self._tmp, self.path)
        return self.path

    def abort(self) -> None:
        """Close and delete the temporary file (the run failed)."""
        try:
            self.stream.disconnect()
        finally:
            self._tmp.unlink(missing_ok=True)

    def __enter__(self) -> Recording:
        return self

    def __exit__(self, exc_type, exc, tb) -> bool:
        if exc_type is None:
            self.close()
        else:
            self.abort()
        return False


def run_name(kind: str, cfg: dict, *extra: str) -> str:
    """The readable recording name of a run: ``"<kind>: <scenario>, seed <N>"`` and ``extra`` (e.g. the medium)."""
    return ", ".join([f"{kind}: {cfg['name']}", *extra, f"seed {cfg['seed']}"])


def recording_name(path) -> str | None:
    """The recording name a ``.rrd`` carries (:func:`run_name`), or None."""
    names = [v for v in load_entities(path).get("/__properties", {}).get("RecordingInfo:name", []) if v]
    return _one(names[-1]) if names else None


def arm_strip(T_world_frames) -> np.ndarray:
    """The arm as a polyline through the origins of its frames ``(..., k, 4, 4)`` -> ``(k, 3)``."""
    return np.asarray(T_world_frames, dtype=float)[..., :3, 3]


def nice_factor(size: float, target: float) -> float:
    """The largest 1-2-5 step ``k`` (..., 10, 20, 50, 100, ...) with ``k * size <= target``; 1 if ``size`` is 0."""
    if not (np.isfinite(size) and size > 0):
        return 1.0
    e = np.floor(np.log10(target / size))
    best = 10.0**(e - 1)
    for m in (1.0, 2.0, 5.0, 10.0):
        if m * 10.0**e * size <= target * (1 + 1e-12):
            best = m * 10.0**e
    return float(best)


def load_blueprint(path) -> dict:
    """The views of the recording's blueprint: ``{view name: {"class": ..., "origin": ..., "contents": [...]}}``.

    Read with rerun's reader (the blueprint store of the ``.rrd``); containers are left out. Empty when the file
    carries no blueprint.
    """
    from rerun.chunk import RrdReader

    reader = RrdReader(str(path))
    rows: dict = {}
    for store in reader.blueprints():
        for chunk in reader.stream(store=store).to_chunks():
            batch = chunk.to_record_batch()
            row = rows.setdefault(chunk.entity_path, {})
            for name in batch.schema.names:
                if ":" in name:
                    values = [v for v in batch.column(name).to_pylist() if v is not None]
                    if values:
                        row[name.split(":", 1)[1]] = values[-1]
    views = {}
    for entity, row in rows.items():
        if "class_identifier" not in row:
            continue
        contents = rows.get(f"{entity}/ViewContents", {}).get("query", [])
        name = row.get("display_name")
        name = name[0] if isinstance(name, list) else name
        origin = row.get("space_origin")
        views[name or entity] = {"class": _one(row["class_identifier"]), "origin": _one(origin),
                                 "contents": list(contents) if isinstance(contents, list) else [contents]}
    return views


def _one(v):
    return v[0] if isinstance(v, list) and len(v) == 1 else v


def load_entities(path) -> dict:
    """Read a recording back with rerun's reader: ``{entity_path: {component: [row values]}}``.

    Component names are rerun's (``"Transform3D:translation"``, ``"Points3D:positions"``, ``"Scalars:scalars"``,
    ...); each value is what one logged row holds (a list for batches). Rows of an entity are in the file's order.
    """
    from rerun.chunk import RrdReader

    out: dict = {}
    for chunk in RrdReader(str(path)).stream().to_chunks():
        batch = chunk.to_record_batch()
        comps = out.setdefault(chunk.entity_path, {})
        for name in batch.schema.names:
            if name.startswith("rerun.controls") or ":" not in name:
                continue
            comps.setdefault(name, []).extend(batch.column(name).to_pylist())
    return out
