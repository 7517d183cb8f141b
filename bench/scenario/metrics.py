"""The metrics each scenario kind writes to ``result.json``, declared in one place.

``tools/gen_reference.py`` writes them into ``docs/reference.md``; the kinds' smoke tests check that a run writes
exactly these names (:func:`check_metrics`: nothing undeclared, nothing declared and unconditional missing), so the
reference cannot drift from the code. A name may hold ``<placeholders>`` (``PLACEHOLDERS``: the values they take).
``when`` says under which configuration a metric appears; metrics without it appear in every successful run (a value
may still be ``null`` when the step it scores failed).
"""

from __future__ import annotations

import re
from typing import NamedTuple


class Metric(NamedTuple):
    """One declared metric: ``name`` (may hold ``<placeholders>``), ``unit``, one-line ``description``, ``when``."""

    name: str
    unit: str
    description: str
    when: str = ""


# placeholder -> (regular expression, what it stands for)
PLACEHOLDERS = {
    "axis": (r"x|y|z", "`x`, `y`, `z`"),
    "method": (r"quaternion_ratio|lms_ratio|quaternion|lms|bundle",
               "`quaternion`, `lms` (RANSAC + the thesis's quaternion / the LMS rotation), `quaternion_ratio`, "
               "`lms_ratio` (the same + error-ratio elimination), `bundle` (the maximum-likelihood bundle, "
               "`pipeline.bundle`)"),
    "at": (r"100|50|min_d|max_d", "intraocular distance d_o: `100`, `50` mm, the smallest (`min_d`) or largest "
                                  "(`max_d`) of `pipeline.intraocular_mm`"),
    "d": (r"[0-9]+(?:\.[0-9]+)?", "any intraocular distance d_o of `pipeline.intraocular_mm`, in mm"),
    "at2": (r"100|50", "d_o = `100` or `50` mm (when in `pipeline.intraocular_mm`)"),
    "index": (r"O[1-5]", "the observability index of `pose_selection.index` (`O1` ... `O5`)"),
    "medium": (r"air_|water_|", "empty, or `air_` / `water_` when `camera.medium: both` (the unprefixed names then "
                                "hold the in-water calibration)"),
    "src": (r"real|sim", "`real` (the photos) or `sim` (their simulation, calibrated by the same code)"),
    "lag": (r"1|2|3", "corners apart: `1`, `2`, `3`"),
    "p": (r"fx_px|fy_px|cx_px|cy_px|k1|k2|p1|p2", "an OpenCV intrinsic: `fx_px`, `fy_px`, `cx_px`, `cy_px` (px), "
                                                 "`k1`, `k2`, `p1`, `p2` (unitless)"),
    "h": (r"s_u|f_px|u0_px|v0_px|k1_per_mm2|k2_per_mm4|T1_per_mm|T2_per_mm",
          "a Heikkilä coefficient in Table 9's units: `s_u`, `f_px`, `u0_px`, `v0_px`, `k1_per_mm2`, `k2_per_mm4`, "
          "`T1_per_mm`, `T2_per_mm`"),
    "z": (r"heikkila|heikkila_jk|oracle|oracle_jk",
          "`heikkila` / `heikkila_jk`: against the true lens with formal / jackknife standard errors; `oracle` / "
          "`oracle_jk`: against the oracle fit"),
    "k": (r"1|2|3", "`1`, `2`, `3` standard errors"),
    "c": (r"alpha|beta", "`alpha` (α) or `beta` (β)"),
    "extractor": (r"thesis|opencv", "corner extractor: `thesis` or `opencv`"),
    "case": (r"d0_[0-9p]+mm_(?:aligned|tilted)", "port case `d0_<lens-to-glass mm>mm_<aligned|tilted>` (a decimal "
                                                 "point written `p`), one per `port.lens_to_glass_mm` × alignment"),
}

# the ``when`` of the metrics many configurations share
BOUND = "`bound.enabled`"
BOUND_NOISY = "`bound.enabled`, features not exact"
BOUND_POSE = "`bound.enabled`, a pose"
REFRACTIVE = "`refractive.enabled`"
MONTE_CARLO = "`monte_carlo.seeds` >= 2"
WEBCAM = "`camera.preset: air_webcam`"

METRICS: dict[str, tuple[Metric, ...]] = {
    "kinematic_identification": (
        Metric("n_identifiable_closed_form", "count", "identifiable errors by the closed-form reduction (Eq. 21, 23, "
               "167): 25 for the TA-40 measured at O6"),
        Metric("rank_numeric", "count", "rank of the stacked identification Jacobian at random poses (SVD)"),
        Metric("closed_vs_numeric_same_columns", "1 / 0", "1 when the numeric choice keeps the closed form's columns"),
        Metric("closed_vs_numeric_map_max_abs_diff", "1", "largest difference between the two reduction maps M"),
        Metric("rank_numeric_off_axis_point", "count", "numeric rank for a point off the joint-6 axis "
               "(`identifiability.off_axis_point_mm`)"),
        Metric("n_identifiable_closed_form_off_axis_point", "count", "closed-form count for that point"),
        Metric("max_abs_reduced_error_linear", "mm or rad", "largest error of the reduced errors ε̇ from the "
               "thesis's linear, noise-free experiment (Eq. 14)"),
        Metric("condition_number_linear", "1", "condition number of the reduced Jacobian G_e, linear experiment"),
        Metric("heldout_rms_mm_uncalibrated", "mm", "held-out RMS position error of the nominal model"),
        Metric("heldout_rms_mm_noise_free_exact", "mm", "held-out RMS after identification on noise-free exact "
               "data (LM)"),
        Metric("iterations_noise_free_exact", "count", "LM iterations of that identification"),
        Metric("identification_s", "s", "time of the iterated (LM) identification of `realistic.n_poses` poses"),
        Metric("identification_linear_s", "s", "time of the linear identification of the same poses"),
        Metric("heldout_rms_mm_calibrated", "mm", "held-out RMS after identification with tracker noise (LM)"),
        Metric("heldout_rms_bound_mm", "mm", "held-out RMS implied by the Cramér-Rao bound of the 25 errors"),
        Metric("heldout_efficiency", "1", "bound / achieved held-out RMS, this draw"),
        Metric("residual_rms_mm", "mm", "RMS residual of the fit"),
        Metric("condition_number", "1", "condition number of the fit's Jacobian"),
        Metric("iterations", "count", "LM iterations"),
        Metric("heldout_rms_mm_calibrated_linear_method", "mm", "held-out RMS of the linear method on the same "
               "noisy exact data"),
        Metric("mc_seeds", "count", "noise draws of the Monte Carlo", MONTE_CARLO),
        Metric("mc_std_ratio_median", "1", "Monte Carlo / predicted standard deviation of ε̇, median over the "
               "errors", MONTE_CARLO),
        Metric("mc_std_ratio_min", "1", "the same, smallest", MONTE_CARLO),
        Metric("mc_std_ratio_max", "1", "the same, largest", MONTE_CARLO),
        Metric("mc_heldout_rms_mm_median", "mm", "held-out RMS, median over the draws", MONTE_CARLO),
        Metric("mc_heldout_rms_mm_rms", "mm", "held-out RMS, RMS over the draws", MONTE_CARLO),
        Metric("mc_heldout_efficiency", "1", "bound / Monte Carlo RMS (1 = the estimator reaches the bound)",
               MONTE_CARLO),
        Metric("pose_selection_<index>_selected", "1", "the index's value for the selected poses"),
        Metric("pose_selection_<index>_random_median", "1", "the index's value for random pose sets, median",
               "`pose_selection.n_random_sets` >= 1"),
        Metric("heldout_rms_mm_selected_poses_median", "mm", "held-out RMS after identification on the selected "
               "poses, median", "`pose_selection.n_random_sets` >= 1"),
        Metric("heldout_rms_mm_random_poses_median", "mm", "the same on random poses",
               "`pose_selection.n_random_sets` >= 1"),
        Metric("ee_pos_err_max_mm", "mm", "§4.6: largest end-effector position deviation after calibration"),
        Metric("ee_rot_err_range_deg", "deg", "§4.6: range of the end-effector orientation deviation"),
        Metric("link5_rot_err_range_deg", "deg", "§4.6: range of link 5's orientation deviation (constant: a bias)"),
        Metric("link5_pos_err_range_mm", "mm", "§4.6: range of link 5's position deviation"),
        Metric("link5_rot_bias_deg_<axis>", "deg", "§4.6: link 5's mean orientation deviation (Eq. 189-194)"),
        Metric("link5_pos_bias_mm_<axis>", "mm", "§4.6: link 5's mean position deviation"),
    ),
    "tracker_base_frame": (
        Metric("base_pos_err_mm_noise_free", "mm", "base origin error from noise-free arcs"),
        Metric("base_rot_err_deg_noise_free", "deg", "base rotation error from noise-free arcs"),
        Metric("base_from_arcs_s", "s", "time of one base-frame fit"),
        Metric("base_pos_err_mm", "mm", "base origin error, one noisy campaign (`noise.default_sigma_mm`)"),
        Metric("base_rot_err_deg", "deg", "base rotation error, the same campaign"),
        Metric("residual_rms_mm", "mm", "RMS residual of the circle fits"),
        Metric("a1_measured_mm", "mm", "DH a1 measured from the two axes (model check)"),
        Metric("alpha1_measured_deg", "deg", "DH α1 measured from the two axes"),
        Metric("arc1_radius_mm", "mm", "radius of the joint-1 arc"),
        Metric("arc2_radius_mm", "mm", "radius of the joint-2 arc"),
        Metric("predicted_pos_std_mm", "mm", "the fit's predicted origin standard deviation (first order)"),
        Metric("predicted_rot_std_deg", "deg", "the fit's predicted rotation standard deviation"),
        Metric("base_pos_err_mm_median", "mm", "origin error, median over the Monte Carlo (default cell)"),
        Metric("base_rot_err_deg_median", "deg", "rotation error, median over the Monte Carlo (default cell)"),
        Metric("pos_rms_over_predicted", "1", "Monte Carlo origin RMS / predicted standard deviation"),
        Metric("rot_rms_over_predicted", "1", "Monte Carlo rotation RMS / predicted standard deviation"),
        Metric("base_pos_bound_mm", "mm", "Cramér-Rao bound of the origin with the joint readings along the arcs"),
        Metric("base_rot_bound_deg", "deg", "Cramér-Rao bound of the rotation"),
        Metric("base_pos_bound_geometry_mm", "mm", "Cramér-Rao bound of the origin from the geometry alone"),
        Metric("base_pos_efficiency", "1", "bound / Monte Carlo RMS, origin"),
        Metric("base_rot_efficiency", "1", "bound / Monte Carlo RMS, rotation"),
        Metric("base_pos_efficiency_geometry", "1", "geometry-only bound / Monte Carlo RMS, origin"),
        Metric("e01_base_shift_mm", "mm", "base shift the arcs report when frames 0-1 carry errors"),
        Metric("e01_base_turn_deg", "deg", "base turn the arcs report when frames 0-1 carry errors"),
        Metric("e01_vs_stated_result_mm", "mm", "that base against T·E0·Tz(y1)·Rz(s1) (Eq. 21's merges), position"),
        Metric("e01_vs_stated_result_deg", "deg", "the same, rotation"),
    ),
    "in_situ": (
        Metric("sim_vs_fk_max_err_m", "m", "simulator check: MuJoCo frames vs our FK, largest difference"),
        Metric("sim_vs_pinocchio_max_err_m", "m", "simulator check: MuJoCo frames vs Pinocchio"),
        Metric("marker_projection_rms_px", "px", "simulator check: rendered markers vs analytic projection, RMS"),
        Metric("marker_projection_max_px", "px", "the same, largest"),
        Metric("markers", "count", "markers found in that check"),
        Metric("depth_has_background", "1 / 0", "the check's depth image holds background (inf)"),
        Metric("distortion_roundtrip_max_px", "px", "distort → undistort round trip over the image, largest error"),
        Metric("render_fps", "1/s", "rendered frames per second (median, wall clock)",
               "views were rendered (not all from the render cache)"),
        Metric("panel_sift_keypoints", "count", "SIFT keypoints in a panel view"),
        Metric("views_rendered", "count", "views rendered (not taken from the cache)"),
        Metric("rig_views_unreachable", "count", "requested lab rig views beyond the joint limits (not rendered; "
                                                 "named on stderr)"),
        Metric("plan_s", "s", "view planning time"),
        Metric("parking_attempts", "count", "ROV parkings drawn until views and valve were reachable"),
        Metric("map_points", "count", "map points ¹p"),
        Metric("inliers", "count", "RANSAC + elimination inliers of the alignment"),
        Metric("integrity_ok", "1 / 0", "1 when the localisation's integrity tests all pass (bench.vision.integrity)"),
        Metric("integrity_refused", "1 / 0", "1 when the integrity tests refuse the pose (do not use it)"),
        Metric("protection_radius_mm", "mm", "protection radius of the base position (covariance inflated by the "
               "integrity tests; null when refused)"),
        Metric("protection_angle_deg", "deg", "protection angle of the base rotation (null when refused)"),
        Metric("integrity_tilt_sq", "1", "test 7: the Mahalanobis square of the located base's tilt against the "
               "vehicle's INS (bench.vision.tilt; refused beyond 13.8)", "the dataset has vehicle.yaml (`vehicle.ins`) "
               "and tests 1-6 did not refuse"),
        Metric("insitu_solve_s", "s", "two new views → base pose (match, triangulate, align, refine), map given"),
        Metric("base_pos_err_mm", "mm", "located base displacement vs the truth, position"),
        Metric("base_rot_err_deg", "deg", "located base displacement vs the truth, rotation"),
        Metric("base_pos_err_<axis>_mm", "mm", "the signed position error (estimate less truth) along the survey "
               "base frame's axis (`bench budget` pairs it seed by seed)"),
        Metric("base_rot_err_<axis>_deg", "deg", "the signed rotation error (rotation vector of the estimate's "
               "rotation times the truth's inverse) along the survey base frame's axis"),
        Metric("base_pos_err_vision_mm", "mm", "the images' pose before the INS's tilt was fused into it, position "
               "(the pose itself when not fused)", "the localisation succeeded"),
        Metric("base_rot_err_vision_deg", "deg", "the same, rotation", "the localisation succeeded"),
        Metric("base_rot_err_vision_tilt_deg", "deg", "its rotation error about the horizontal axes (what the INS's "
               "tilt sees)", "the localisation succeeded"),
        Metric("base_rot_err_vision_heading_deg", "deg", "its rotation error about the vertical (the heading)",
               "the localisation succeeded"),
        Metric("base_pos_err_bundle_mm", "mm", "the thesis estimator (refine bundle) beside refine joints, position",
               "`pipeline.refine: joints`"),
        Metric("base_rot_err_bundle_deg", "deg", "the same, rotation", "`pipeline.refine: joints`"),
        Metric("base_pos_std_mm", "mm", "the pipeline's reported position uncertainty", "the localisation succeeded"),
        Metric("base_rot_std_deg", "deg", "the pipeline's reported rotation uncertainty",
               "the localisation succeeded"),
        Metric("valve_tool_err_mm", "mm", "true tool tip vs true valve handle centre after re-targeting the taught "
               "task through the calibrated arm"),
        Metric("valve_tool_err_<axis>_mm", "mm", "the signed tool-tip error (tip less handle centre) along the "
               "world axis"),
        Metric("valve_tool_err_uncompensated_mm", "mm", "the same when the taught readings are replayed"),
        Metric("valve_protection_radius_mm", "mm", "protection radius of the re-targeted tool tip: the base "
               "covariance carried to the taught tip (lever arm from the base origin), as `protection_radius_mm`",
               "a taught task; the localisation not refused"),
        Metric("keypoint_sigma_px", "px", "SIFT keypoint noise of the survey views, measured against the true "
               "epipolar curves (robust σ)", BOUND),
        Metric("keypoint_sigma_matches", "count", "matches behind that σ", BOUND),
        Metric("keypoint_sigma_bound_px", "px", "the bound's noise in the reference and survey views: "
               "`keypoint_sigma_px` × `keypoint_fisher_factor`", BOUND),
        Metric("keypoint_sigma_locate_px", "px", "the locate views' own keypoint noise (the other parking's "
               "viewpoint): `keypoint_sigma_px` × `keypoint_locate_ratio` × `keypoint_locate_fisher_factor`; the "
               "bound's noise there", BOUND),
        Metric("keypoint_fisher_factor", "1", "σ of the Fisher information of the survey views' keypoint errors "
               "(a Gaussian scale mixture fitted to them on the panel's true surfaces) over their robust σ: what "
               "the heavy tails take from the information", BOUND_POSE),
        Metric("keypoint_locate_fisher_factor", "1", "the same for the locate views' errors", BOUND_POSE),
        Metric("keypoint_field_offset_px", "px", "the keypoints' errors that move a whole view's keypoints together: "
               "the sd of each view's offset (per axis), measured on the panel's true surfaces over the survey and "
               "locate views beyond what their white noise scatters (bench.scenario.bounds.measure_field: a "
               "polynomial of bound.keypoint_field_order over the image, in each view's modes orthonormal over its "
               "keypoints; a mode's sd is its RMS displacement over them)", BOUND_POSE),
        Metric("keypoint_field_slope_px", "px", "the same field's slope modes (x, y): the sd of each", BOUND_POSE),
        Metric("keypoint_field_quadratic_px", "px", "its quadratic modes (bound.keypoint_field_order >= 2; x², x y, "
               "y² orthogonalised against the lower degrees)", BOUND_POSE),
        Metric("keypoint_field_cubic_px", "px", "its cubic modes (order 3) likewise", BOUND_POSE),
        Metric("keypoint_field_views", "count", "views behind that field", BOUND_POSE),
        Metric("keypoint_twin_points", "count", "map keypoints that are another's second SIFT orientation (the "
               "same pixel): the map merges them (pipeline.twin_keypoints once), holds both (both, the default) or "
               "holds both at the shared keypoint's worth (weighted); "
               "the bound counts each detection once (bench.vision.insitu.one_per_detection)", BOUND),
        Metric("keypoint_locate_ratio", "1", "the locate views' keypoint noise over the survey's, on the same "
               "tracks, measured on the panel's true surfaces (robust σ)", BOUND_POSE),
        Metric("keypoint_locate_points", "count", "tracks behind that ratio", BOUND_POSE),
        Metric("base_pos_bound_mm", "mm", "the limit of the base position: Cramér-Rao bound ⊕ model floor "
               "(root-sum-square); with the INS's tilt when the pipeline fused it", BOUND),
        Metric("base_rot_bound_deg", "deg", "the limit of the base rotation: bound ⊕ floor", BOUND),
        Metric("base_pos_bound_vision_mm", "mm", "the limit without the INS's tilt (the same as `base_pos_bound_mm` "
               "when it was not fused)", BOUND),
        Metric("base_rot_bound_vision_deg", "deg", "the same, rotation", BOUND),
        Metric("base_pos_crb_mm", "mm", "Cramér-Rao bound of the base position (pixels as matched, encoders, arm, "
               "intrinsics and mount covariances; the INS's tilt when the pipeline fused it)", BOUND),
        Metric("base_rot_crb_deg", "deg", "Cramér-Rao bound of the base rotation", BOUND),
        Metric("base_rot_crb_tilt_deg", "deg", "the bound without the INS about the horizontal axes (RMS of the two)",
               BOUND),
        Metric("base_rot_crb_heading_deg", "deg", "the bound without the INS about the vertical", BOUND),
        Metric("base_pos_crb_mc_mm", "mm", "Monte Carlo of refine joints under exactly the bound's model (RMS)",
               "`bound.ml_trials` > 0"),
        Metric("base_rot_crb_mc_deg", "deg", "the same, rotation", "`bound.ml_trials` > 0"),
        Metric("base_pos_floor_mm", "mm", "model floor: base position error on noise-free features through the true "
               "optics with the best central camera", BOUND),
        Metric("base_rot_floor_deg", "deg", "model floor, rotation", BOUND),
        Metric("base_pos_floor_calibrated_mm", "mm", "the same with the lab's calibrated camera (mount by AX = XB "
               "on the true arm): what the calibrated central model leaves", BOUND),
        Metric("base_rot_floor_calibrated_deg", "deg", "the same, rotation", BOUND),
        Metric("floor_misfit_px", "px", "RMS pixel misfit of the best central camera to the true optics over the "
               "observations", BOUND),
        Metric("base_pos_bound_mc_mm", "mm", "Monte Carlo of the pipeline's estimator on ideal features, position",
               BOUND),
        Metric("base_rot_bound_mc_deg", "deg", "the same, rotation", BOUND),
        Metric("bound_observations", "count", "image observations in the bound", BOUND),
        Metric("bound_s", "s", "time of the bound", BOUND),
        Metric("base_pos_efficiency", "1", "bound / achieved, position (over seeds: RMS bound / RMS error)", BOUND),
        Metric("base_rot_efficiency", "1", "bound / achieved, rotation", BOUND),
        Metric("focal_err_pct", "%", "calibrated focal length vs the true (in water: paraxial; refractive: the "
               "lens's) one"),
        Metric("reproj_rms_px", "px", "reprojection RMS of the lab camera calibration"),
        Metric("reproj_rms_central_px", "px", "the same of the central calibration it starts from",
               "`pipeline.camera_model: refractive`"),
        Metric("port_d0_err_mm", "mm", "calibrated lens-to-glass distance vs the true one (decentre absorbed)",
               "`pipeline.camera_model: refractive`"),
        Metric("port_d0_std_mm", "mm", "its standard deviation from the calibration (prior included)",
               "`pipeline.camera_model: refractive`"),
        Metric("port_tilt_err_deg", "deg", "calibrated port tilt vs the true one", "`pipeline.camera_model: "
               "refractive`"),
        Metric("mount_pos_err_mm", "mm", "calibrated camera mount vs the true (in water: virtual centre; refractive: "
               "the lens), position"),
        Metric("mount_pos_err_lens_centre_mm", "mm", "calibrated mount position vs the lens itself"),
        Metric("mount_rot_err_deg", "deg", "calibrated camera mount, rotation error"),
        Metric("arm_heldout_rms_mm", "mm", "lab-calibrated arm vs the true arm, RMS over 500 held-out poses"),
    ),
    "xy_table": (
        Metric("views_rendered", "count", "views rendered (not taken from the cache)"),
        Metric("camera_centre_vs_readings_max_mm", "mm", "simulator check: camera centres vs the table readings"),
        Metric("sim_s", "s", "simulation time"),
        Metric("render_fps", "1/s", "rendered frames per second", "views were rendered"),
        Metric("reproj_rms_px", "px", "reprojection RMS of the rig calibration", "`pipeline.camera: calibrated`"),
        Metric("calibration_views_used", "count", "rig views the calibration used", "`pipeline.camera: calibrated`"),
        Metric("focal_err_pct", "%", "the pipeline's focal length vs the true lens"),
        Metric("eq199_baseline_mm", "mm", "Eq. 199's intraocular distance for `pipeline.depth_resolution_mm`"),
        Metric("corner_views_lost", "count", "table views whose rig corners were not found",
               "`pipeline.features: corners`"),
        Metric("bias_rot_err_deg", "deg", "estimated camera orientation bias R0 vs the truth (angle)"),
        Metric("theta_<axis>0_true_deg", "deg", "true bias angle θx0, θy0, θz0 (Eq. 197)"),
        Metric("theta_<axis>0_deg", "deg", "estimated bias angle", "the search found it"),
        Metric("theta_<axis>0_err_deg", "deg", "estimated − true bias angle", "the search found it"),
        Metric("truth_injected", "count", "evaluator-side truth injections (camera, mount bias, features)"),
        Metric("combinations_total", "count", "view pairs evaluated over all d_o"),
        Metric("estimates_failed", "count", "pairs whose localisation failed"),
        Metric("keypoints_median", "count", "features per table view, median"),
        Metric("keypoints_reference", "count", "features in the reference view"),
        Metric("map_points_median", "count", "map points per pair, median", "a pair succeeded"),
        Metric("pairs_3d_median", "count", "3D pairs per estimate, median", "a pair succeeded"),
        Metric("inliers_median", "count", "RANSAC inliers per estimate, median", "a pair succeeded"),
        Metric("keypoint_sigma_px", "px", "feature noise measured against the truth", BOUND),
        Metric("keypoint_sigma_matches", "count", "matches behind that σ", BOUND),
        Metric("table_reading_rms_mm", "mm", "table readings vs the carriage's true position, RMS", BOUND),
        Metric("table_reading_rms_deg", "deg", "the same for the rotary stage", BOUND),
        Metric("bound_pose_check_mm", "mm", "the bound's table model vs the simulator's camera poses", BOUND_NOISY),
        Metric("bound_mc_failures", "count", "failed draws of the ideal estimator's Monte Carlo",
               "`bound.enabled`, `bound.mc_trials` > 0"),
        Metric("bound_points", "count", "map points in the bound", BOUND_NOISY),
        Metric("bound_observations_median", "count", "observations per bound, median", BOUND_NOISY),
        Metric("<method>_err_pos_at_<at>_mm", "mm", "3D RMS position error over the pairs at that d_o"),
        Metric("<method>_err_<axis>_mm_at_<at>", "mm", "RMS position error along one table axis at that d_o "
               "(Tables 5-8, 11-14)"),
        Metric("lms_ratio_err_pos_at_<d>_mm", "mm", "LMS + error ratio: 3D RMS error at every d_o"),
        Metric("lms_ratio_bound_pos_at_<d>_mm", "mm", "the limit of that 3D error: the complete Cramér-Rao bound "
               "(table errors, intrinsics, R0) ⊕ the model floor", BOUND_NOISY),
        Metric("lms_ratio_bound_<axis>_mm_at_<at2>", "mm", "the limit along one axis", BOUND_NOISY),
        Metric("lms_ratio_crb_<axis>_mm_at_<at2>", "mm", "the complete Cramér-Rao bound alone along one axis",
               BOUND_NOISY),
        Metric("lms_ratio_floor_<axis>_mm_at_<at2>", "mm", "the model floor along one axis: the estimator on "
               "noise-free features through the true optics with the best central camera", BOUND_NOISY),
        Metric("calibration_fx_std_px", "px", "standard deviation of the calibrated fx: the calibration's covariance "
               "plus what the rig's stated tolerances (target.yaml) leave in it", "`pipeline.camera: calibrated`"),
        Metric("floor_failures", "count", "estimates of the model floor's run that failed", BOUND_NOISY),
        Metric("floor_misfit_px", "px", "RMS pixel misfit of the best central camera to the true optics", BOUND_NOISY),
        Metric("bound_intrinsics_free", "1 / 0", "1 when the bound takes the intrinsics under the calibration's "
               "covariance (`pipeline.camera: calibrated`)", BOUND_NOISY),
        Metric("bound_R0_free", "1 / 0", "1 when the bound estimates R0 with the camera positions "
               "(`pipeline.mount_bias: estimated`)", BOUND_NOISY),
        Metric("bound_centre_free", "1 / 0", "1 when the bound takes the camera centre on the stage under the "
               "tolerance table.yaml states (`sim.camera_centre_tolerance_mm`)", BOUND_NOISY),
        Metric("bound_distortion_free", "1 / 0", "1 when the bound takes the distortion under the pipeline's stated "
               "prior (`pipeline.bundle`, `pipeline.bundle_distortion_sigma`)", BOUND_NOISY),
        Metric("lms_ratio_bound_mc_pos_at_<at2>_mm", "mm", "the ideal estimator's Monte Carlo, 3D RMS", BOUND_NOISY),
        Metric("lms_ratio_efficiency_at_<at2>", "1", "limit / achieved 3D error", BOUND_NOISY),
        Metric("bundle_efficiency_at_<at2>", "1", "limit / achieved 3D error of the bundle (the same limit)",
               "`bound.enabled`, features not exact, `pipeline.bundle`"),
        Metric("bound_rot_at_<at2>_deg", "deg", "rotation bound at that d_o", BOUND_NOISY),
    ),
    "camera_replica": (
        Metric("photos", "count", "photos in `photos.dir`"),
        Metric("<src>_views", "count", "photos (renders) where the board was found"),
        Metric("<src>_rms_px", "px", "calibration residual RMS over all corners"),
        Metric("<src>_per_view_rms_cv", "1", "spread of the per-view RMS (std / mean)"),
        Metric("<src>_row_corr_lag<lag>", "1", "correlation of residual vectors that many corners apart along a board "
               "row, pooled over views (0: white noise; 1: a shift common to the row)"),
        Metric("<src>_col_corr_lag<lag>", "1", "the same along a board column"),
        Metric("<src>_sift_plane_px", "px", "SIFT's localisation noise on the board plane (homography transfer "
               "between views, robust σ / √2)"),
        Metric("<src>_edge_sigma_px", "px", "edge spread: median erf sigma of profiles across the square edges"),
        Metric("<src>_edge_undershoot_dn", "DN", "how far the median edge profile dips below the black level beside "
               "the edge (a camera's sharpening halo)"),
        Metric("<src>_noise_black_dn", "DN", "noise inside the black squares (std after a plane fit, grey)"),
        Metric("<src>_level_black_dn", "DN", "grey level of the black squares (median)"),
        Metric("rms_ratio", "1", "simulated / real calibration RMS (issue 12: 0.7-1.3)"),
        Metric("sift_ratio", "1", "simulated / real SIFT noise on the plane"),
        Metric("sim_focal_error_pct", "%", "the replica's calibrated fx against its true one (the photos' fx)"),
    ),
    "camera_calibration": (
        Metric("<medium>sim_table_pose_err_m", "m", "simulator check: table poses vs the commanded ones"),
        Metric("<medium>views_rendered", "count", "views rendered (not taken from the cache)"),
        Metric("<medium>render_s", "s", "render time"),
        Metric("<medium>plan_render_s", "s", "planning + render time"),
        Metric("<medium>reproj_rms_px", "px", "reprojection RMS χ (Eq. 196) of the multi-view calibration"),
        Metric("<medium>opencv_reproj_rms_px", "px", "cv2.calibrateCamera on the same detections"),
        Metric("<medium>reproj_minus_opencv_px", "px", "ours − OpenCV (≤ 0: never worse)"),
        Metric("<medium>focal_err_pct", "%", "the worse of the fx, fy errors (in water vs the paraxial focal length)"),
        Metric("<medium>fx_err_pct", "%", "fx error (signed)"),
        Metric("<medium>fy_err_pct", "%", "fy error (signed)"),
        Metric("<medium>opencv_focal_err_pct", "%", "OpenCV's focal error"),
        Metric("<medium>corner_rms_px", "px", "extracted corners vs their true projections, RMS"),
        Metric("<medium>corner_max_px", "px", "the same, largest"),
        Metric("<medium>corner_duplicate_matches", "count", "true corners matched twice (should be 0)"),
        Metric("<medium>corner_rms_px_first_pass", "px", "corner RMS before the refinement in ideal pixels "
               "(null without `pipeline.refine_corners`)"),
        Metric("<medium>corner_rms_px_<extractor>_extractor", "px", "corner RMS of that extractor (the one used, "
               "and the other with `pipeline.compare_extractors`)"),
        Metric("<medium>views_found_<extractor>_extractor", "count", "views the other extractor found",
               "`pipeline.compare_extractors`"),
        Metric("<medium>model_floor_rms_px", "px", "the oracle's RMS: the model fitted to exact projections"),
        Metric("<medium>oracle_focal_err_pct", "%", "the oracle's focal error"),
        Metric("<medium>views_used", "count", "views calibrated"),
        Metric("<medium>views_skipped", "count", "views without a usable corner set"),
        Metric("<medium>points", "count", "corners calibrated"),
        Metric("<medium>sigma_px", "px", "noise σ estimated from the residuals"),
        Metric("<medium>jackknife_s", "s", "time of the jackknife over views"),
        Metric("<medium>err_<p>", "unit of the parameter", "estimate − truth (null in water except fx, fy)"),
        Metric("<medium>std_<p>", "unit of the parameter", "standard error: the formal one, sqrt of the diagonal of "
               "σ²(JᵀJ)⁻¹, plus the rig's stated tolerances when `<medium>tolerance_draws` > 0"),
        Metric("<medium>jk_std_<p>", "unit of the parameter", "jackknife standard error over views"),
        Metric("<medium>err_<h>", "unit of the coefficient", "Heikkilä coefficient: estimate − truth",
               "the underwater camera"),
        Metric("<medium>std_<h>", "unit of the coefficient", "standard error (`heikkila_covariance` of the same "
               "covariance: formal, plus the rig's stated tolerances when `<medium>tolerance_draws` > 0)",
               "the underwater camera"),
        Metric("<medium>jk_std_<h>", "unit of the coefficient", "jackknife standard error",
               "the underwater camera"),
        Metric("<medium><z>_within_<k>std", "count", "coefficients within k standard errors (null in water for the "
               "true lens)"),
        Metric("<medium><z>_max_abs_z", "1", "largest |estimate − reference| / standard error"),
        Metric("<medium>heikkila_n_coeffs", "count", "coefficients fitted"),
        Metric("<medium>tolerance_draws", "count", "calibrations against rigs drawn from target.yaml's stated "
               "tolerances behind the covariance (0: none stated, or `pipeline.target_tolerance: false`)"),
        Metric("table3_alpha_mean_err_pct", "%", "Table 3: average per-view α vs the true fx", WEBCAM),
        Metric("table3_beta_mean_err_pct", "%", "Table 3: average per-view β vs the true fy", WEBCAM),
        Metric("table3_theta_mean_deg", "deg", "Table 3: average per-view skew angle θ", WEBCAM),
        Metric("table3_chi_mean_px", "px", "Table 3: average per-view χ (corners by `pipeline.table3_edges`: the "
               "edge map's pixels as printed, or sub-pixel)", WEBCAM),
        Metric("table3_chi_subpixel_mean_px", "px", "the same χ on the thesis extractor's corners from sub-pixel "
               "edge positions (the bench's addition; null with the OpenCV extractor)", WEBCAM),
        Metric("table3_<c>_std_px", "px", "Table 3: sample std of the per-view α (`alpha`) or β (`beta`) over the "
               "pictures", WEBCAM),
        Metric("thesis_table3_<c>_std_px", "px", "the same std over the thesis's seven pictures", WEBCAM),
        Metric("focal_ratio_water_air", "1", "focal length in water / in air (paraxial: 1.34)",
               "`camera.medium: both`"),
        Metric("thesis_focal_ratio_water_air", "1", "the thesis's Table 15 / Table 9 focal lengths",
               "`camera.medium: both`"),
    ),
    "flatport_study": (
        Metric("threshold_px", "px", "the image error below which the polynomial model is good enough"),
        Metric("calib_rms_px_<case>", "px", "reprojection RMS of the noise-free rig calibration"),
        Metric("rms_px_at_calib_<case>", "px", "image RMS error over the whole image at the calibration distance"),
        Metric("rms_px_at_0p2m_<case>", "px", "image RMS error at 0.2 m (the nearest distance)"),
        Metric("max_px_at_0p2m_<case>", "px", "largest image error at 0.2 m"),
        Metric("rms_px_at_3m_<case>", "px", "image RMS error at 3 m (the farthest distance)"),
        Metric("max_px_at_3m_<case>", "px", "largest image error at 3 m"),
        Metric("rms_mm_at_0p2m_<case>", "mm", "object-space RMS error (point to fitted ray) at 0.2 m"),
        Metric("rms_mm_at_3m_<case>", "mm", "object-space RMS error at 3 m"),
        Metric("polynomial_ok_from_m_<case>", "m", "near edge of the window where the error is below the threshold "
               "(null: none)"),
        Metric("polynomial_ok_to_m_<case>", "m", "far edge of that window (null: none)"),
        Metric("refractive_needed_below_m_<case>", "m", "a refractive model is needed nearer than this"),
        Metric("refractive_needed_above_m_<case>", "m", "a refractive model is needed farther than this"),
        Metric("refractive_needed_everywhere_<case>", "1 / 0", "1 when no distance is within the threshold"),
        Metric("centre_offset_axial_mm_<case>", "mm", "fitted camera centre along the axis, relative to the lens "
               "(negative: behind)"),
        Metric("centre_offset_lateral_mm_<case>", "mm", "fitted camera centre off the axis"),
        Metric("centre_rotation_deg_<case>", "deg", "fitted camera frame's rotation relative to the lens"),
        Metric("paraxial_centre_axial_mm_<case>", "mm", "the port's paraxial virtual centre along the axis"),
        Metric("calib_coverage_<case>", "1", "fraction of the image the calibration corners cover"),
        Metric("refractive_rms_px_at_calib_<case>", "px", "the refractive model (calibrated from the same views with "
               "refractive.noise_px of noise): image RMS error at the calibration distance", REFRACTIVE),
        Metric("refractive_rms_px_at_0p2m_<case>", "px", "the same at 0.2 m", REFRACTIVE),
        Metric("refractive_rms_px_at_3m_<case>", "px", "the same at 3 m", REFRACTIVE),
        Metric("refractive_d0_err_mm_<case>", "mm", "its lens-to-glass distance's error", REFRACTIVE),
        Metric("refractive_calib_rms_px_<case>", "px", "its calibration's reprojection RMS (noise included)",
               REFRACTIVE),
        Metric("central_noisy_rms_px_at_0p2m_<case>", "px", "the Heikkilä fit of the same noisy views: image RMS "
               "error at 0.2 m", REFRACTIVE),
        Metric("central_noisy_rms_px_at_3m_<case>", "px", "the same at 3 m", REFRACTIVE),
        Metric("central_noisy_rms_px_at_calib_<case>", "px", "the same at the calibration distance", REFRACTIVE),
        Metric("frame_reproj_rms_px_<case>", "px", "calibration corners reprojected with one camera frame for all "
               "views"),
    ),
}


def _regex(name: str) -> re.Pattern:
    parts = re.split(r"<([a-z0-9]+)>", name)
    out = []
    for i, part in enumerate(parts):
        if i % 2:
            if part not in PLACEHOLDERS:
                raise KeyError(f"metric {name!r}: unknown placeholder <{part}>")
            out.append(f"(?:{PLACEHOLDERS[part][0]})")
        else:
            out.append(re.escape(part))
    return re.compile("".join(out) + r"\Z")


def check_metrics(kind: str, names) -> tuple[list[str], list[str]]:
    """``(undeclared, missing)``: written names no declaration matches, and unconditional declarations (no
    ``when``) that no written name matches. Both empty when a run of ``kind`` writes what ``METRICS`` declares."""
    declared = METRICS[kind]
    patterns = [(m, _regex(m.name)) for m in declared]
    names = list(names)
    undeclared = [n for n in names if not any(p.match(n) for _, p in patterns)]
    missing = [m.name for m, p in patterns if not m.when and not any(p.match(n) for n in names)]
    return undeclared, missing
