"""The native peer of the bundle benchmarks: Ceres (SPARSE_SCHUR) through pycolmap / pyceres.

A lidarcat :class:`~lidarcat.bundle.BundleProblem` becomes a pycolmap
``Reconstruction`` (one SIMPLE_PINHOLE camera per focal length, principal point 0,
intrinsics constant; every photo an image with ``cam_from_world``; every point a
``Point3D`` with its track), adjusted by pycolmap's Ceres bundle adjuster, whose
``problem`` (a ``pyceres.Problem``) also receives the control points as
``pyceres.factors.NormalPrior`` blocks on the points' own coordinates (pycolmap
hands out views of its memory).  So Ceres minimises exactly lidarcat's v'Pv / 2:

* frames: lidarcat projects ``u = M (X - X0)``, ``x = -f u_x / u_z``,
  ``y = -f u_y / u_z`` (image y up, camera looking down -z); COLMAP projects
  ``p = R X + t``, ``x = f p_x / p_z``, ``y = f p_y / p_z`` (y down, looking +z).
  With ``R = D M``, ``D = diag(1, -1, -1)`` and ``t = -R X0``, COLMAP's
  ``(x, y)`` is lidarcat's ``(x, -y)``.
* weights: the image coordinates and the focal length are divided by the
  observations' common sd (mm), so the unit residuals are lidarcat's
  ``v / sd``; control points get ``NormalPrior(mean, diag(sd^2))``.

Requires the ``bench`` extra (pyceres, pycolmap).  Only problems with one image
sd for all observations and no camera constraints are supported (the synthetic
benchmark blocks).
"""

from __future__ import annotations

import time

import numpy as np

D = np.diag([1.0, -1.0, -1.0])


def solve_with_ceres(problem, eo: np.ndarray, pts: np.ndarray, *, threads: int = 2, max_iter: int = 50,
                     linear_solver: str = "SPARSE_SCHUR", preconditioner: str | None = None) -> dict:
    """Adjust *problem* from (eo (P, 6), pts (Q, 3)) with Ceres; returns final_cost, iterations,
    seconds (the solve only), eo, points, report.

    *linear_solver* and *preconditioner* are Ceres enum names (``ITERATIVE_SCHUR`` with
    ``SCHUR_JACOBI``, ``CLUSTER_JACOBI`` or ``CLUSTER_TRIDIAGONAL``: Ceres's step solvers whose
    cost per step grows linearly with the block)."""
    import pyceres
    import pycolmap
    from scipy.spatial.transform import Rotation

    from lidarcat.geometry.collinearity import rotation_matrix

    p = problem
    sd = np.unique(p.sd_mm)
    if len(sd) != 1 or p.eo_constraint_photo_index is not None:
        raise ValueError("the Ceres peer needs one image sd for all observations and no camera constraints")
    sd = float(sd[0])
    # a local origin: with X0 ~ 7e6 m, t = -R X0 ties every rotation to huge translations and
    # Ceres crawls (51 iterations without converging on 100 photos); shifting is exact
    origin = np.round(eo[:, :3].mean(axis=0))
    eo = np.column_stack([eo[:, :3] - origin, eo[:, 3:]])
    pts = pts - origin
    rec = pycolmap.Reconstruction()
    cam_of_focal = {}
    for f in np.unique(p.focal_length_mm):
        cid = len(cam_of_focal) + 1
        cam = pycolmap.Camera(model="SIMPLE_PINHOLE", width=100000, height=100000,
                              params=[f / sd, 0.0, 0.0], camera_id=cid)
        rec.add_camera_with_trivial_rig(cam)
        cam_of_focal[float(f)] = cid
    order = np.argsort(p.photo_index, kind="stable")
    starts = np.searchsorted(p.photo_index[order], np.arange(p.n_photos + 1))
    xy = np.column_stack([p.xy_mm[:, 0], -p.xy_mm[:, 1]]) / sd
    R = D @ rotation_matrix(eo[:, 3:])
    t = -np.einsum("pij,pj->pi", R, eo[:, :3])
    quat = Rotation.from_matrix(R).as_quat()                       # x, y, z, w (Eigen order)
    elem_img, elem_idx = np.empty(len(order), dtype=np.int64), np.empty(len(order), dtype=np.int64)
    for i in range(p.n_photos):
        obs = order[starts[i]:starts[i + 1]]
        img = pycolmap.Image(name=str(p.photo_ids[i]), points2D=[pycolmap.Point2D(v) for v in xy[obs]],
                             camera_id=cam_of_focal[float(p.focal_length_mm[i])], image_id=i + 1)
        rec.add_image_with_trivial_frame(img, pycolmap.Rigid3d(pycolmap.Rotation3d(quat[i]), t[i]))
        elem_img[obs] = i + 1
        elem_idx[obs] = np.arange(len(obs))
    by_pt = np.argsort(p.point_index, kind="stable")
    pstarts = np.searchsorted(p.point_index[by_pt], np.arange(p.n_points + 1))
    pid = np.empty(p.n_points, dtype=np.int64)
    for j in range(p.n_points):
        tr = pycolmap.Track()
        for a in by_pt[pstarts[j]:pstarts[j + 1]]:
            tr.add_element(int(elem_img[a]), int(elem_idx[a]))
        pid[j] = rec.add_point3D(pts[j], tr)
    config = pycolmap.BundleAdjustmentConfig()
    for i in range(p.n_photos):
        config.add_image(i + 1)
    for cid in cam_of_focal.values():
        config.set_constant_cam_intrinsics(cid)
    opts = pycolmap.BundleAdjustmentOptions()
    opts.refine_focal_length = False
    opts.refine_principal_point = False
    opts.refine_extra_params = False
    opts.ceres.auto_select_solver_type = False
    so = opts.ceres.solver_options
    so.linear_solver_type = getattr(pyceres.LinearSolverType, linear_solver)
    if preconditioner:
        so.preconditioner_type = getattr(pyceres.PreconditionerType, preconditioner)
    so.num_threads = threads
    so.max_num_iterations = max_iter
    so.function_tolerance = 1e-8
    so.gradient_tolerance = 1e-12
    so.parameter_tolerance = 1e-9
    opts.ceres.min_num_residuals_for_cpu_multi_threading = 1
    ba = pycolmap.create_default_ceres_bundle_adjuster(opts, config, rec)
    prob = ba.problem
    for j, enh, csd in zip(p.constraint_point_index, p.constraint_enh_m, p.constraint_sd_m):
        free = ~np.isfinite(csd)
        if free.any():
            raise ValueError("the Ceres peer needs control points with all three sigmas")
        xyz = rec.points3D[int(pid[j])].xyz
        if not prob.has_parameter_block(xyz):
            raise RuntimeError("pycolmap did not expose the point's own memory")
        prob.add_residual_block(pyceres.factors.NormalPrior(np.asarray(enh, float) - origin, np.diag(csd**2)),
                                None, [xyz])
    t0 = time.perf_counter()
    summary = ba.solve().ceres_summary
    seconds = time.perf_counter() - t0
    out_pts = np.array([rec.points3D[int(q)].xyz for q in pid]) + origin
    return {"final_cost": float(summary.final_cost), "initial_cost": float(summary.initial_cost),
            "iterations": int(summary.num_successful_steps + summary.num_unsuccessful_steps),
            "seconds": seconds, "points": out_pts, "report": summary.BriefReport()}


def solve_bal_with_ceres(problem, *, threads: int = 2, max_iter: int = 50) -> dict:
    """A :class:`lidarcat.bundle.bal.BalProblem` adjusted by Ceres through pycolmap.

    Every BAL camera is a COLMAP ``RADIAL`` camera (f, cx = cy = 0 constant, k1,
    k2; the same distortion polynomial) of its own image.  BAL cameras look
    along -z (``p = -P_xy / P_z``), COLMAP's along +z; with ``cam_from_world =
    (D R(r), D t)``, ``D = diag(-1, 1, -1)`` (a rotation), COLMAP's ``P'_xy / P'_z``
    is ``(-p_x, p_y)``, so the observations enter with x negated and the cost is
    BAL's ``0.5 sum r^2``.  Ceres's defaults of its BAL example: SPARSE_SCHUR,
    function tolerance 1e-6.  Returns final_cost, initial_cost, iterations,
    seconds (the solve only) and the report.
    """
    import pyceres
    import pycolmap
    from scipy.spatial.transform import Rotation

    from lidarcat.bundle.bal import _rodrigues

    p = problem
    Dm = np.diag([-1.0, 1.0, -1.0])
    obs_px = p.observations_px * np.array([-1.0, 1.0])
    R, _ = _rodrigues(p.cameras[:, :3])
    R = Dm @ R
    t = p.cameras[:, 3:6] @ Dm
    quat = Rotation.from_matrix(R).as_quat()
    rec = pycolmap.Reconstruction()
    order = np.argsort(p.camera_index, kind="stable")
    starts = np.searchsorted(p.camera_index[order], np.arange(p.n_cameras + 1))
    elem_img = np.empty(len(order), dtype=np.int64)
    elem_idx = np.empty(len(order), dtype=np.int64)
    for i in range(p.n_cameras):
        f, k1, k2 = p.cameras[i, 6:9]
        rec.add_camera_with_trivial_rig(pycolmap.Camera(model="RADIAL", width=4000, height=4000,
                                                        params=[f, 0.0, 0.0, k1, k2], camera_id=i + 1))
        obs = order[starts[i]:starts[i + 1]]
        img = pycolmap.Image(name=str(i), points2D=[pycolmap.Point2D(v) for v in obs_px[obs]],
                             camera_id=i + 1, image_id=i + 1)
        rec.add_image_with_trivial_frame(img, pycolmap.Rigid3d(pycolmap.Rotation3d(quat[i]), t[i]))
        elem_img[obs] = i + 1
        elem_idx[obs] = np.arange(len(obs))
    by_pt = np.argsort(p.point_index, kind="stable")
    pstarts = np.searchsorted(p.point_index[by_pt], np.arange(p.n_points + 1))
    for j in range(p.n_points):
        tr = pycolmap.Track()
        for a in by_pt[pstarts[j]:pstarts[j + 1]]:
            tr.add_element(int(elem_img[a]), int(elem_idx[a]))
        rec.add_point3D(p.points[j], tr)
    config = pycolmap.BundleAdjustmentConfig()
    for i in range(p.n_cameras):
        config.add_image(i + 1)
    opts = pycolmap.BundleAdjustmentOptions()
    opts.refine_focal_length = True
    opts.refine_principal_point = False
    opts.refine_extra_params = True
    opts.ceres.auto_select_solver_type = False
    opts.ceres.min_num_residuals_for_cpu_multi_threading = 1
    so = opts.ceres.solver_options
    so.linear_solver_type = pyceres.LinearSolverType.SPARSE_SCHUR
    so.num_threads = threads
    so.max_num_iterations = max_iter
    so.function_tolerance = 1e-6
    so.gradient_tolerance = 1e-10
    so.parameter_tolerance = 1e-8
    ba = pycolmap.create_default_ceres_bundle_adjuster(opts, config, rec)
    t0 = time.perf_counter()
    summary = ba.solve().ceres_summary
    seconds = time.perf_counter() - t0
    return {"final_cost": float(summary.final_cost), "initial_cost": float(summary.initial_cost),
            "iterations": int(summary.num_successful_steps + summary.num_unsuccessful_steps),
            "seconds": seconds, "report": summary.BriefReport()}
