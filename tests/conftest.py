"""The tests marked ``slow``, each with the test of the default run that checks the same behaviour.

The default test command deselects ``slow`` (``addopts`` in
``pyproject.toml``) to stay under about 15 minutes on two CPU cores;
``python -m pytest -m slow`` and ``benchmarks/run_slow_tests.py`` run them.
A test is listed here only where a faster test of the same behaviour stays
in the default run (the value). The marks are set by test id so that single
cases of a parametrized test can be marked;
``test_layout.py::test_slow_marks_name_existing_tests`` checks that every id
names a test that exists, so that a renamed test cannot drop its mark
silently.
"""

import pytest

#: Test id -> the default test(s) that check the same behaviour.
SLOW = {
    "test_protocol.py::test_adapted_methods_can_continue_the_plain_pretrained_model": (
        "test_protocol.py::test_pretrain_models_continue_from (continue_from) and "
        "test_protocol.py::test_sweep_adapted_methods_run_beside_the_paper_methods "
        "(the adapted variant in the protocol)"
    ),
    "test_distributed.py::test_dask_cluster_gives_the_local_results": (
        "test_protocol.py::test_same_schedule_gives_identical_results (parallel tasks give "
        "the sequential results) and test_distributed.py::test_reproduce_backend_dask_* "
        "(the dask backend and its workers)"
    ),
    "test_export.py::test_onnx_matches_predict_for_any_number_of_motors[1-GRUResidual-float32]": (
        "the same test for [1-GRUResidual-float64] and [3-GRUResidual-float32]"
    ),
    "test_export.py::test_onnx_matches_predict_for_any_number_of_motors[3-GRUResidual-float64]": (
        "the same test for [1-GRUResidual-float64] and [3-GRUResidual-float32]"
    ),
    "test_control.py::test_feedforward_recovers_the_motor_path_of_the_model_tips[play-PDLBackbone]": (
        "the same test for [play-PCCBackbone] and [None-PDLBackbone]"
    ),
    "test_online.py::test_step_with_a_play_matches_predict[none-PDLBackbone-numpy]": (
        "the same test for [none-PDLBackbone-numba] and [none-PCCBackbone-numpy]"
    ),
    "test_online.py::test_step_with_a_play_matches_predict[gru-PDLBackbone-numpy]": (
        "the same test for [gru-PDLBackbone-numba] and [gru-PCCBackbone-numpy]"
    ),
    "test_online_pickle.py::test_pickled_estimator_with_a_play_steps_on_as_the_original[numpy]": (
        "the same test for [numba]; test_online_pickle.py::test_pickled_estimator_steps_on_as_"
        "the_original (the numpy engine)"
    ),
    "test_hysteresis.py::test_predict_and_calibrate_keep_nothing_and_change_no_input[PDLBackbone]": (
        "the same test for [PCCBackbone]"
    ),
    "test_hysteresis.py::test_identification_reads_sweep_rows_only[PDLBackbone]": (
        "the same test for [PCCBackbone]"
    ),
    "test_export_step.py::test_exported_step_matches_predict[pdl-play-gru-2m]": (
        "the same test for [pcc-play-gru-2m] (the GRU) and [pdl-play-mlp-2m] (PDL with a play)"
    ),
    # the gallery examples: each one's calls are checked by the tests named
    "test_examples.py::test_example_runs[plot_steering.py]": "test_control.py",
    "test_examples.py::test_example_runs[plot_rig_without_sweep.py]": (
        "test_rigs.py::test_learner_without_sweep_fits_and_predicts"
    ),
    "test_examples.py::test_example_runs[plot_motor_count.py]": "test_instruments.py",
    "test_examples.py::test_example_runs[plot_group_cross_validation.py]": (
        "test_residuals.py::test_cross_validate_with_groups, test_model_selection.py"
    ),
    "test_examples.py::test_example_runs[plot_grid_search.py]": (
        "test_residuals.py::test_grid_search_over_backbones_and_residuals"
    ),
    "test_examples.py::test_example_runs[plot_export_step.py]": (
        "test_export_step.py::test_exported_step_matches_predict"
    ),
    "test_examples.py::test_example_runs[plot_compare_backbones.py]": (
        "test_backbones.py, test_pcc.py, test_pdl.py"
    ),
    "test_examples.py::test_example_runs[plot_residual_pipeline.py]": (
        "test_residuals.py::test_pipeline_fit_predict"
    ),
    "test_examples.py::test_example_runs[plot_shaft_recovery.py]": (
        "test_online.py::test_resweep_keeps_the_calibration_and_renews_the_context, "
        "test_recalibration.py"
    ),
    "test_examples.py::test_example_runs[plot_streaming.py]": (
        "test_online.py::test_step_matches_predict, test_export.py"
    ),
    "test_examples.py::test_example_runs[plot_benchmark.py]": "test_datasets.py",
}


def _test_id(item):
    """``file.py::name[params]`` of a collected test."""
    return f"{item.path.name}::{item.name}"


@pytest.hookimpl(tryfirst=True)  # before ``-m`` deselects by the marks
def pytest_collection_modifyitems(config, items):
    for item in items:
        if _test_id(item) in SLOW:
            item.add_marker(pytest.mark.slow)
