"""Tests of the evaluation protocol: training sets, predictions, tables and report.

The protocol runs once (module fixture) on a small part of the simulated
benchmark with a tiny schedule (one epoch, small networks). The training
stages are observed through wrappers around ``_pretrain`` and ``_finetune``
that record what each model is trained and evaluated on and then call the
original functions, so the recorded run is an ordinary protocol run.
"""

import copy
import dataclasses

import numpy as np
import pandas as pd
import pytest
from numpy.testing import assert_allclose, assert_array_equal
from sklearn.utils._param_validation import InvalidParameterError

from skcath.backbones import BACKBONE_COLUMNS, PCCBackbone, PDLBackbone
from skcath.metrics import error_cdf, paired_reduction, per_run_rmse
from skcath.protocol import (
    ADAPTED_METHOD,
    BUDGET_METHODS,
    COMPARISONS,
    FULL,
    LEARNER_COLUMNS,
    LOCO_METHOD,
    LOCO_METHODS,
    MAIN_METHODS,
    METHODS,
    PROPOSED_METHOD,
    QUICK,
    ROLES,
    TORQUE_CONTEXT,
    VARIANTS,
    Schedule,
    backbone_method,
    calibrate_backbones,
    compute_tables,
    format_report,
    get_schedule,
    learner_input,
    make_learner,
    methods_with_role,
    pretrain_models,
    protocol_folds,
    run_protocol,
    write_results,
)
from skcath.protocol import _protocol
from skcath.protocol._report import TABLE_FILES

from _helpers import benchmark_settings, tiny_schedule

N_BOOTSTRAP = 200
EXCLUDED = "S00"
#: Settings kept from the benchmark (per catheter): enough for two setting folds.
SETTINGS = ("S00", "S01", "S02", "S03", "S04", "S05", "S06")
SEEDS = (0, 1)
LEARNED = ("PDL+GRU", "PDL+MLP")

TINY = tiny_schedule(seeds=SEEDS, variants=LEARNED)


# ---------------------------------------------------------------------------
# fixtures
# ---------------------------------------------------------------------------
@pytest.fixture(scope="module")
def data():
    """Two catheters, one run per setting, settings S00-S06 (14 runs)."""
    X, y = benchmark_settings(SETTINGS)
    assert X["run"].nunique() == 2 * len(SETTINGS)
    return X, y


def _runs(X):
    return set(X["run"].astype(str))


def _run_table(X):
    """catheter and setting (str) of every run id (str)."""
    runs = X.drop_duplicates("run")[["run", "catheter", "setting"]].astype(str)
    return runs.set_index("run")


@pytest.fixture(scope="module")
def recorded(data):
    """One protocol run with every pretraining and fine-tuning call recorded."""
    X, y = data
    calls = {"pretrain": [], "finetune": [], "learners": []}
    original_pretrain, original_finetune = _protocol._pretrain, _protocol._finetune
    original_make_learner = _protocol._make_learner

    def make_learner(variant, seed, params):
        learner = original_make_learner(variant, seed, params)
        calls["learners"].append({"variant": variant, "seed": seed, "params": params, "learner": learner})
        return learner

    # the protocol gives each task at most one test set (the budget experiment several)
    def pretrain(key, params, X_train, y_train, X_tests):
        out = original_pretrain(key, params, X_train, y_train, X_tests)
        calls["pretrain"].append({
            "key": key, "params": params, "X_train": X_train, "y_train": y_train,
            "n_tests": len(X_tests), "n_preds": len(out[2]),
            "X_test": X_tests[0] if X_tests else None, "model": out[1],
            "pred": out[2][0] if out[2] else None,
        })
        return out

    def finetune(key, params, pretrained, X_train, y_train, X_tests):
        out = original_finetune(key, params, pretrained, X_train, y_train, X_tests)
        calls["finetune"].append({
            "key": key, "params": params, "pretrained": pretrained, "X_train": X_train,
            "y_train": y_train, "n_tests": len(X_tests), "n_preds": len(out[2]),
            "X_test": X_tests[0], "pred": out[2][0],
        })
        return out

    with pytest.MonkeyPatch.context() as mp:
        mp.setattr(_protocol, "_pretrain", pretrain)
        mp.setattr(_protocol, "_finetune", finetune)
        mp.setattr(_protocol, "_make_learner", make_learner)
        result = run_protocol(X, y, schedule=TINY, exclude_settings=[EXCLUDED], n_jobs=1)
    return result, calls


@pytest.fixture(scope="module")
def result(recorded):
    return recorded[0]


@pytest.fixture(scope="module")
def calls(recorded):
    return recorded[1]


@pytest.fixture(scope="module")
def tables(result):
    return compute_tables(result, n_bootstrap=N_BOOTSTRAP, random_state=0)


# ---------------------------------------------------------------------------
# what every model is trained and evaluated on
# ---------------------------------------------------------------------------
def test_number_of_trained_models(calls, result):
    n_catheters, n_folds = 2, 2
    n_models = len(LEARNED) * len(SEEDS)
    assert len(calls["pretrain"]) == n_catheters * n_models
    assert len(calls["finetune"]) == n_catheters * n_folds * n_models
    timings = result.timings
    assert set(timings.columns) >= {"stage", "variant", "seed", "catheter", "seconds"}
    assert (timings["stage"] == "pretrain").sum() == n_catheters * n_models
    assert (timings["stage"] == "fine-tune").sum() == n_catheters * n_folds * n_models
    assert (timings["seconds"] > 0).all()
    keys = {(c["key"]["variant"], c["key"]["seed"], c["key"]["catheter"]) for c in calls["pretrain"]}
    assert keys == {(v, s, c) for v in LEARNED for s in SEEDS for c in ("C1", "C2")}


def test_pretraining_never_sees_the_held_out_catheter(calls, data):
    X, _ = data
    info = _run_table(X)
    for call in calls["pretrain"]:
        held_out = call["key"]["catheter"]
        train_runs = _runs(call["X_train"])
        own = set(info.index[info["catheter"] == held_out])
        other = set(info.index[info["catheter"] != held_out])
        assert not train_runs & own
        # every run of the other catheters, the excluded setting included
        assert train_runs == other
        assert EXCLUDED in set(info.loc[sorted(train_runs), "setting"])


def test_loco_predictions_cover_the_evaluated_runs_of_the_held_out_catheter(calls, data):
    X, _ = data
    info = _run_table(X)
    for call in calls["pretrain"]:
        held_out = call["key"]["catheter"]
        if call["key"]["variant"] != "PDL+GRU":
            assert call["n_tests"] == call["n_preds"] == 0
            continue
        assert call["n_tests"] == call["n_preds"] == 1
        expected = set(info.index[(info["catheter"] == held_out) & (info["setting"] != EXCLUDED)])
        assert _runs(call["X_test"]) == expected
        assert np.isfinite(call["pred"]).all()


def test_finetuning_sets_exclude_the_fold_test_runs(calls, data):
    X, _ = data
    info = _run_table(X)
    for call in calls["finetune"]:
        assert call["n_tests"] == call["n_preds"] == 1
        catheter = call["key"]["catheter"]
        train_runs, test_runs = _runs(call["X_train"]), _runs(call["X_test"])
        own = set(info.index[info["catheter"] == catheter])
        assert train_runs and test_runs
        assert not train_runs & test_runs
        assert train_runs <= own  # only the held-out catheter's runs
        assert test_runs <= own
        # the rest of the catheter, the excluded setting included, is training data
        assert train_runs | test_runs == own
        assert EXCLUDED in set(info.loc[sorted(train_runs), "setting"])
        assert EXCLUDED not in set(info.loc[sorted(test_runs), "setting"])


def test_each_evaluated_run_is_tested_exactly_once_per_model(calls, data):
    X, _ = data
    info = _run_table(X)
    for variant in LEARNED:
        for seed in SEEDS:
            for catheter in ("C1", "C2"):
                tested = [
                    _runs(c["X_test"]) for c in calls["finetune"]
                    if (c["key"]["variant"], c["key"]["seed"], c["key"]["catheter"])
                    == (variant, seed, catheter)
                ]
                assert len(tested) == 2
                assert not tested[0] & tested[1]
                expected = set(info.index[(info["catheter"] == catheter) & (info["setting"] != EXCLUDED)])
                assert tested[0] | tested[1] == expected


def test_finetuning_starts_from_the_matching_pretrained_model(calls):
    pretrained = {
        (c["key"]["variant"], c["key"]["seed"], c["key"]["catheter"]): c["model"]
        for c in calls["pretrain"]
    }
    for call in calls["finetune"]:
        key = (call["key"]["variant"], call["key"]["seed"], call["key"]["catheter"])
        assert call["pretrained"] is pretrained[key]
        expected = type(pretrained[key]).__name__
        assert expected == ("GRUResidual" if VARIANTS[key[0]][0] == "gru" else "MLPResidual")
        assert pretrained[key].random_state == key[1]


def test_finetuned_learners_load_the_pretrained_weights_and_statistics(calls):
    pretrained = [c["model"] for c in calls["pretrain"]]
    learners = calls["learners"]
    assert len(learners) == len(calls["pretrain"]) + len(calls["finetune"])
    fresh = [c for c in learners if "pretrained" not in c["params"]]
    tuned = [c for c in learners if "pretrained" in c["params"]]
    assert {id(c["learner"]) for c in fresh} == {id(m) for m in pretrained}
    assert len(tuned) == len(calls["finetune"])
    for call in tuned:
        source = call["params"]["pretrained"].estimator
        assert any(source is m for m in pretrained)
        assert (call["variant"], call["seed"]) == (
            "PDL+GRU" if type(source).__name__ == "GRUResidual" else "PDL+MLP", source.random_state
        )
        model = call["learner"]
        # normalisation statistics come from the pretraining data
        assert_array_equal(model.sigma_e_, source.sigma_e_)
        # fine-tuning changed the weights
        state, start = model.module_.state_dict(), source.module_.state_dict()
        assert state.keys() == start.keys()
        assert any(not np.array_equal(state[k].numpy(), start[k].numpy()) for k in state)


def test_stage_parameters_follow_the_schedule(calls):
    for call in calls["pretrain"]:
        assert call["params"] == {**TINY.model_params, **TINY.pretrain_params}
    for call in calls["finetune"]:
        assert call["params"] == {**TINY.model_params, **TINY.finetune_params}


def test_training_targets_are_aligned_with_the_rows(calls, data):
    """Every y passed to a fit is the measured tip of the rows of its X."""
    X, y = data
    for call in calls["pretrain"] + calls["finetune"]:
        rows = call["X_train"].index.to_numpy()
        assert_array_equal(call["X_train"]["run"].astype(str).to_numpy(), X["run"].astype(str).to_numpy()[rows])
        assert_array_equal(call["y_train"], y[rows])


def test_test_inputs_carry_no_motion_measurement(calls):
    """Held-out runs reach the models only with their sweep reference."""
    tests = [c["X_test"] for c in calls["finetune"]]
    tests += [c["X_test"] for c in calls["pretrain"] if c["X_test"] is not None]
    for X_test in tests:
        motion = (X_test["phase"].astype(str) == "motion").to_numpy()
        assert motion.any() and (~motion).any()
        assert np.isnan(X_test.loc[motion, ["ref_x", "ref_y", "ref_z"]].to_numpy()).all()
        assert not {"p_x", "p_y", "p_z"} & set(X_test.columns)


def test_learners_get_the_pdl_backbone_columns(calls, result, data):
    X, _ = data
    pdl = PDLBackbone().fit(X).transform(X)[list(BACKBONE_COLUMNS)].to_numpy()
    for call in calls["finetune"][:2] + calls["pretrain"][:1]:
        for frame in (call["X_train"], call["X_test"]):
            assert_allclose(frame[list(BACKBONE_COLUMNS)].to_numpy(), pdl[frame.index.to_numpy()])


# ---------------------------------------------------------------------------
# the result
# ---------------------------------------------------------------------------
def test_evaluated_rows_are_the_non_excluded_runs(result, data):
    X, y = data
    keep = (X["setting"].astype(str) != EXCLUDED).to_numpy()
    assert len(result.X) == keep.sum()
    assert_array_equal(result.X["run"].astype(str).to_numpy(), X.loc[keep, "run"].astype(str).to_numpy())
    assert_array_equal(result.X["t"].to_numpy(), X.loc[keep, "t"].to_numpy())
    assert_array_equal(result.y, y[keep])
    assert EXCLUDED not in set(result.X["setting"].astype(str))
    assert result.exclude_settings == (EXCLUDED,)
    assert result.schedule is TINY


def test_every_method_and_seed_predicts_every_evaluated_row(result):
    preds = result.predictions
    # a fixed order, whatever order the parallel tasks finish in
    assert list(preds) == ["PCC", "PDL", *LEARNED, "PDL+GRU (LOCO)"]
    assert set(preds["PCC"]) == {None} and set(preds["PDL"]) == {None}
    for method in (*LEARNED, "PDL+GRU (LOCO)"):
        assert list(preds[method]) == list(SEEDS)
    for by_seed in preds.values():
        for values in by_seed.values():
            assert values.shape == (len(result.X), 3)
            assert np.isfinite(values).all()


def test_learned_predictions_depend_on_stage_and_seed(result):
    preds = result.predictions
    gru, loco, pdl = preds["PDL+GRU"], preds["PDL+GRU (LOCO)"], preds["PDL"][None]
    assert not np.allclose(gru[0], loco[0])  # fine-tuning changed the model
    assert not np.allclose(gru[0], gru[1])  # the seeds give different models
    assert not np.allclose(gru[0], pdl)  # the residual corrects the backbone
    assert not np.allclose(gru[0], preds["PDL+MLP"][0])


def test_loco_prediction_is_the_pretrained_model_applied_to_the_catheter(calls, result):
    call = next(c for c in calls["pretrain"] if c["key"]["variant"] == "PDL+GRU" and c["key"]["seed"] == 1)
    catheter = call["key"]["catheter"]
    rows = (result.X["catheter"].astype(str) == catheter).to_numpy()
    assert_allclose(result.predictions["PDL+GRU (LOCO)"][1][rows], call["pred"])


def test_backbone_predictions_match_the_backbones(result):
    # The backbones calibrate each run on its own sweep: two runs suffice.
    runs = [result.X.loc[result.X["catheter"].astype(str) == c, "run"].iloc[0] for c in ("C1", "C2")]
    rows = result.X["run"].isin(runs).to_numpy()
    Xr = result.X[rows]
    assert_allclose(result.predictions["PCC"][None][rows], PCCBackbone().fit(Xr).predict(Xr), rtol=1e-9, atol=1e-9)
    assert_allclose(result.predictions["PDL"][None][rows], PDLBackbone().fit(Xr).predict(Xr), rtol=1e-9, atol=1e-9)


def test_same_schedule_gives_identical_results(result, tables, data):
    X, y = data
    # in parallel, the tasks finish in another order: nothing may depend on it
    again = run_protocol(X, y, schedule=TINY, exclude_settings=[EXCLUDED], n_jobs=2)
    assert list(again.predictions) == list(result.predictions)
    for method, by_seed in result.predictions.items():
        for seed, values in by_seed.items():
            assert_array_equal(again.predictions[method][seed], values)
    tables_again = compute_tables(again, n_bootstrap=N_BOOTSTRAP, random_state=0)
    assert set(tables_again) == set(tables)
    for key, table in tables.items():
        pd.testing.assert_frame_equal(tables_again[key], table)


# ---------------------------------------------------------------------------
# tables
# ---------------------------------------------------------------------------
def _hand_run_rmse(result, method):
    """Per-run RMSE averaged over seeds, recomputed with per_run_rmse."""
    per_seed = [per_run_rmse(result.y, pred, result.X) for pred in result.predictions[method].values()]
    rmse = pd.concat(per_seed, axis=1).mean(axis=1)
    rmse.index = rmse.index.astype(str)
    return rmse


def test_table_1_layout_and_values(tables, result):
    table = tables["table_1"]
    assert list(table.index) == ["PCC", "PDL", "PDL+GRU"]
    assert list(table.columns) == ["C1", "C2", "pooled"]
    catheter = _run_table(result.X)["catheter"]
    for method in table.index:
        rmse = _hand_run_rmse(result, method)
        by_catheter = rmse.groupby(catheter.reindex(rmse.index)).mean()
        assert_allclose(table.loc[method, ["C1", "C2"]].to_numpy(float), by_catheter[["C1", "C2"]].to_numpy())
        assert table.loc[method, "pooled"] == pytest.approx(rmse.mean(), rel=1e-12)


def test_pooled_is_the_mean_over_runs_not_over_samples(tables, result):
    motion = (result.X["phase"].astype(str) == "motion").to_numpy()
    err = np.linalg.norm(result.predictions["PDL"][None] - result.y, axis=1)[motion]
    sample_rmse = np.sqrt(np.nanmean(err**2))
    rmse = _hand_run_rmse(result, "PDL")
    assert tables["table_1"].loc["PDL", "pooled"] == pytest.approx(rmse.mean())
    assert tables["table_1"].loc["PDL", "pooled"] != pytest.approx(sample_rmse, rel=1e-6)


def test_run_tables(tables, result):
    run_rmse = tables["run_rmse"]
    assert list(run_rmse.columns) == ["method", "catheter", "setting", "run", "rmse_mm"]
    evaluated = _runs(result.X)
    for method in result.predictions:
        sub = run_rmse[run_rmse["method"] == method]
        assert set(sub["run"]) == evaluated and len(sub) == len(evaluated)
    info = _run_table(result.X)
    expected = info.reindex(run_rmse["run"])
    assert_array_equal(run_rmse["catheter"].to_numpy(), expected["catheter"].to_numpy())
    assert_array_equal(run_rmse["setting"].to_numpy(), expected["setting"].to_numpy())

    by_seed = tables["run_rmse_by_seed"]
    gru = by_seed[by_seed["method"] == "PDL+GRU"]
    assert set(gru["seed"]) == set(SEEDS)
    assert len(gru) == len(SEEDS) * len(evaluated)
    mean = gru.groupby("run")["rmse_mm"].mean()
    sub = run_rmse[run_rmse["method"] == "PDL+GRU"].set_index("run")["rmse_mm"]
    assert_allclose(sub.reindex(mean.index).to_numpy(), mean.to_numpy(), rtol=1e-12)
    seeds = gru.pivot(index="run", columns="seed", values="rmse_mm")
    assert not np.allclose(seeds[0], seeds[1])  # the average is over distinct values
    assert_allclose(sub.reindex(mean.index).to_numpy(), _hand_run_rmse(result, "PDL+GRU").reindex(mean.index))


def test_cdf_at_5mm(tables, result):
    at5 = tables["cdf_at_5mm"].iloc[:, 0]
    assert set(at5.index) == set(result.predictions)
    for method, by_seed in result.predictions.items():
        fractions = [error_cdf(result.y, pred, result.X, [5.0]).iloc[0] for pred in by_seed.values()]
        assert at5[method] == pytest.approx(100 * np.mean(fractions), rel=1e-12)
    assert ((at5 >= 0) & (at5 <= 100)).all()
    cdf = tables["cdf"]
    for _, curve in cdf.groupby("method"):
        assert np.all(np.diff(curve.sort_values("error_mm")["fraction"].to_numpy()) >= 0)


def test_paired_reductions_match_paired_reduction(tables, result):
    paired = tables["paired"]
    wide = tables["run_rmse"].pivot(index="run", columns="method", values="rmse_mm")
    info = _run_table(result.X).reindex(wide.index)
    clusters = info["catheter"] + "/" + info["setting"]
    rows = paired[paired["comparison"] == "PDL -> PDL+GRU"].set_index("scope")
    assert list(rows.index) == ["C1", "C2", "pooled"]
    assert (rows["baseline"] == "PDL").all() and (rows["candidate"] == "PDL+GRU").all()
    for scope in rows.index:
        runs = wide.index if scope == "pooled" else info.index[info["catheter"] == scope]
        expected = paired_reduction(
            wide.loc[runs, "PDL"], wide.loc[runs, "PDL+GRU"], clusters.loc[runs],
            n_bootstrap=N_BOOTSTRAP, random_state=0,
        )
        for column in ("reduction_mm", "ci_low_mm", "ci_high_mm", "reduction_pct", "fraction_improved"):
            assert rows.loc[scope, column] == pytest.approx(expected[column], rel=1e-12, abs=1e-12), column
        assert rows.loc[scope, "n_runs"] == len(runs)
    # comparisons whose methods were not run are left out
    assert set(paired["comparison"]) == {
        "PCC -> PDL+GRU", "PDL -> PDL+GRU", "PDL+MLP -> PDL+GRU", "catheter held out -> setting held out",
    }


def test_paired_reduction_is_the_difference_of_the_table_means(tables):
    paired = tables["paired"]
    table_1 = tables["table_1"]
    rows = paired[paired["comparison"] == "PCC -> PDL+GRU"].set_index("scope")
    for scope in ("C1", "C2", "pooled"):
        expected = table_1.loc["PCC", scope] - table_1.loc["PDL+GRU", scope]
        assert rows.loc[scope, "reduction_mm"] == pytest.approx(expected, rel=1e-9)


def test_residual_learners_and_ablation_tables(tables):
    learners = tables["residual_learners"]
    assert list(learners.index[:2]) == ["PDL+MLP", "PDL+GRU"]
    assert {"reduction_mm", "ci_low_mm", "ci_high_mm", "fraction_improved"} <= set(learners.index)
    assert_allclose(
        learners.loc["reduction_mm"].to_numpy(float),
        (learners.loc["PDL+MLP"] - learners.loc["PDL+GRU"]).to_numpy(float),
        rtol=1e-9,
    )
    # only the full model of the torque x context grid was run: no ablation table
    assert "table_2" not in tables
    assert "Table II." not in format_report(tables)


def test_ablation_table_when_ablations_were_run(result):
    """Table II lists each torque/context combination that was run, with its own errors."""
    ablated = {seed: pred + 1.0 for seed, pred in result.predictions["PDL+GRU"].items()}
    with_ablation = copy.copy(result)
    with_ablation.predictions = {**result.predictions, "PDL+GRU (no context)": ablated}
    tables = compute_tables(with_ablation, n_bootstrap=N_BOOTSTRAP, random_state=0)
    table_2 = tables["table_2"]
    assert list(table_2.index) == [("Yes", "No"), ("Yes", "Yes")]
    assert_allclose(table_2.loc[("Yes", "Yes")].to_numpy(float), tables["table_1"].loc["PDL+GRU"].to_numpy(float))
    assert (table_2.loc[("Yes", "No")] > table_2.loc[("Yes", "Yes")]).all()
    paired = tables["paired"].set_index(["comparison", "scope"])
    assert paired.loc[("context (with torque)", "pooled"), "reduction_mm"] > 0
    assert "Table II." in format_report(tables)


def test_sweep_adapted_methods_run_beside_the_paper_methods(data, result):
    """The adapted variant learns on the played backbone; the paper's methods are unchanged."""
    X, y = data
    schedule = tiny_schedule(seeds=(0,), variants=("PDL+GRU", "PDL+GRU+adapt"))
    adapted = run_protocol(X, y, schedule=schedule, exclude_settings=[EXCLUDED], n_jobs=1)
    names = {"PCC", "PDL", "PDL+adapt", "PDL+GRU", "PDL+GRU+adapt", "PDL+GRU (LOCO)",
             "PDL+GRU+adapt (LOCO)"}
    assert set(adapted.predictions) == names
    for name in names:
        assert all(np.isfinite(p).all() for p in adapted.predictions[name].values()), name
    # adding the adapted variant leaves the paper's methods as they were, to the bit
    for name in ("PDL", "PDL+GRU", "PDL+GRU (LOCO)"):
        assert_array_equal(adapted.predictions[name][None if name == "PDL" else 0],
                           result.predictions[name][None if name == "PDL" else 0])
    played = PDLBackbone(hysteresis="play").fit(adapted.X).predict(adapted.X)
    assert_allclose(adapted.predictions["PDL+adapt"][None], played, rtol=1e-9, atol=1e-9)
    assert not np.allclose(adapted.predictions["PDL+GRU+adapt"][0], adapted.predictions["PDL+GRU"][0])

    tables = compute_tables(adapted, n_bootstrap=N_BOOTSTRAP, random_state=0)
    table = tables["adaptation"]
    assert list(table.index) == [
        "PDL", "PDL+adapt", "PDL+GRU", "PDL+GRU+adapt", "PDL+GRU (LOCO)", "PDL+GRU+adapt (LOCO)",
        "ratio PDL+GRU+adapt / PDL", "ratio PDL+GRU+adapt (LOCO) / PDL+GRU",
    ]
    assert_allclose(table.loc["ratio PDL+GRU+adapt / PDL"].to_numpy(float),
                    (table.loc["PDL+GRU+adapt"] / table.loc["PDL"]).to_numpy(float))
    assert_allclose(table.loc["PDL+GRU"].to_numpy(float), tables["table_1"].loc["PDL+GRU"].to_numpy(float))
    paired = tables["paired"].set_index(["comparison", "scope"])
    assert ("sweep adaptation (catheter held out)", "pooled") in paired.index
    assert "Sweep adaptation" in format_report(tables)
    assert "adaptation" not in compute_tables(result, n_bootstrap=N_BOOTSTRAP, random_state=0)


def test_adapted_methods_can_continue_the_plain_pretrained_model(data, result):
    """With adapt_pretrain_params the adapted variant continues PDL+GRU's pretrained model.

    Its numbers do not depend on whether PDL+GRU itself is reported: the
    protocol pretrains the start it needs when the plain variant is not run.
    """
    X, y = data
    base = tiny_schedule(seeds=(0,), variants=("PDL+GRU", "PDL+GRU+adapt"))
    schedule = dataclasses.replace(base, adapt_pretrain_params={"max_epochs": 1, "lr": 3e-3})
    both = run_protocol(X, y, schedule=schedule, exclude_settings=[EXCLUDED], n_jobs=1)
    alone = run_protocol(X, y, schedule=dataclasses.replace(schedule, variants=("PDL+GRU+adapt",)),
                         exclude_settings=[EXCLUDED], n_jobs=1)
    scratch = run_protocol(X, y, schedule=base, exclude_settings=[EXCLUDED], n_jobs=1)
    for name in ("PDL+GRU+adapt", "PDL+GRU+adapt (LOCO)"):
        assert_array_equal(alone.predictions[name][0], both.predictions[name][0])
        assert not np.allclose(both.predictions[name][0], scratch.predictions[name][0])
    assert "PDL+GRU" not in alone.predictions
    # the start was trained (and timed) even though PDL+GRU is not reported
    stages = alone.timings.groupby(["stage", "variant"]).size()
    assert stages["pretrain", "PDL+GRU"] == stages["pretrain", "PDL+GRU+adapt"] == 2
    for name in ("PDL+GRU", "PDL+GRU (LOCO)"):
        assert_array_equal(both.predictions[name][0], result.predictions[name][0])


def test_pretrain_models_continue_from(data):
    """continue_from starts each model from its given model's weights and statistics."""
    X, y = data
    X_learner = learner_input(X)
    schedule = tiny_schedule(seeds=(0,), variants=("PDL+GRU",))
    folds = protocol_folds(X_learner, schedule, exclude_settings=EXCLUDED).loco
    start = pretrain_models(X_learner, y, folds, schedule).models
    same = pretrain_models(X_learner, y, folds, dataclasses.replace(schedule, adapt_pretrain_params={"max_epochs": 0}),
                           continue_from=start).models
    more = pretrain_models(X_learner, y, folds, dataclasses.replace(schedule, adapt_pretrain_params={"max_epochs": 1}),
                           continue_from=start).models
    assert same.keys() == more.keys() == start.keys()
    for key, model in start.items():
        weights = model.module_.state_dict()
        kept, moved = same[key].module_.state_dict(), more[key].module_.state_dict()
        assert all(np.array_equal(kept[k].numpy(), weights[k].numpy()) for k in weights)
        assert any(not np.array_equal(moved[k].numpy(), weights[k].numpy()) for k in weights)
        assert_array_equal(more[key].sigma_e_, model.sigma_e_)
    with pytest.raises(ValueError, match="adapt_pretrain_params"):
        pretrain_models(X_learner, y, folds, schedule, continue_from=start)


def test_loco_table(tables):
    loco = tables["loco"]
    assert list(loco.index) == ["PDL", "PDL+GRU", "PDL+GRU (LOCO)", "runs below 4 mm (LOCO, %)"]
    run_rmse = tables["run_rmse"]
    sub = run_rmse[run_rmse["method"] == "PDL+GRU (LOCO)"]
    for scope in ("C1", "C2", "pooled"):
        runs = sub if scope == "pooled" else sub[sub["catheter"] == scope]
        assert loco.loc["PDL+GRU (LOCO)", scope] == pytest.approx(runs["rmse_mm"].mean())
        assert loco.loc["runs below 4 mm (LOCO, %)", scope] == pytest.approx(100 * (runs["rmse_mm"] < 4.0).mean())
    assert_allclose(loco.loc["PDL"].to_numpy(float), tables["table_1"].loc["PDL"].to_numpy(float))


def test_magnitude_and_time_tables(tables):
    magnitude, time_table = tables["magnitude"], tables["time"]
    assert {"PCC", "PDL", *LEARNED} <= set(magnitude.columns)
    bins = tables["magnitude_bins"]
    pdl = bins[bins["method"] == "PDL"]
    expected = pdl.groupby(["bin_left", "bin_right"])["rmse_mm"].median()
    assert_allclose(magnitude["PDL"].reindex(expected.index).to_numpy(), expected.to_numpy())
    assert magnitude.index.is_monotonic_increasing and time_table.index.is_monotonic_increasing
    # late bins reached by fewer than 90 % of the runs are dropped
    n_runs = tables["run_rmse"]["run"].nunique()
    counts = tables["time_bins"].groupby(["method", "bin_left"])["run"].nunique()
    assert (counts >= 0.9 * n_runs).all()
    example = tables["example"]
    assert list(example.columns) == ["t", "p_x", "p_y", "p_z", "phat_x", "phat_y", "phat_z"]
    assert example["t"].iloc[0] == 0 and example["t"].iloc[-1] <= 60.0


# ---------------------------------------------------------------------------
# report and files
# ---------------------------------------------------------------------------
def test_format_report(tables, result):
    text = format_report(tables, result)
    for title in (
        "Table I.", "Residual learners", "Leave one catheter out",
        "Samples below 5 mm", "RMSE by motor-input magnitude", "RMSE over motion time",
        "Paired reductions",
    ):
        assert title in text
    assert "schedule: tiny (2 setting folds per catheter, seeds [0, 1])" in text
    assert f"{result.X['run'].nunique()} evaluated runs" in text
    assert "not evaluated: ['S00']" in text
    pdl_pooled = f"{tables['table_1'].loc['PDL', 'pooled']:.1f}"
    table_1 = text.split("Table I.")[1].split("\n\n")[0]
    assert pdl_pooled in table_1
    # without the result there is no header line
    assert not format_report(tables).startswith("schedule")


def test_write_results_csv(tables, tmp_path):
    paths = write_results(tables, tmp_path / "out", figures=False)
    expected = {name for key, name in TABLE_FILES.items() if key in tables}
    assert {p.name for p in paths} == expected
    assert {p.name for p in (tmp_path / "out").iterdir()} == expected
    run_rmse = pd.read_csv(tmp_path / "out" / TABLE_FILES["run_rmse"])
    assert list(run_rmse.columns) == list(tables["run_rmse"].columns)
    assert_allclose(run_rmse["rmse_mm"], tables["run_rmse"]["rmse_mm"], rtol=1e-5)
    table_1 = pd.read_csv(tmp_path / "out" / TABLE_FILES["table_1"], index_col=0)
    assert list(table_1.index) == ["PCC", "PDL", "PDL+GRU"]
    assert_allclose(table_1.to_numpy(), tables["table_1"].to_numpy(float), rtol=1e-5)
    paired = pd.read_csv(tmp_path / "out" / TABLE_FILES["paired"])
    assert len(paired) == len(tables["paired"])


def test_write_results_figures(tables, tmp_path):
    pytest.importorskip("matplotlib")
    paths = write_results(tables, tmp_path, figures=True)
    pngs = {p.name for p in paths if p.suffix == ".png"}
    assert pngs == {
        "rmse_boxes.png", "residual_learners.png", "new_catheter.png", "error_cdf.png",
        "error_by_magnitude.png", "error_over_time.png", "motion_example.png",
        "paired_reductions.png",
    }
    for name in pngs:
        assert (tmp_path / name).read_bytes()[:8] == b"\x89PNG\r\n\x1a\n"


# ---------------------------------------------------------------------------
# schedules and errors
# ---------------------------------------------------------------------------
def test_named_schedules():
    assert get_schedule("full") is FULL and get_schedule("quick") is QUICK
    assert FULL.n_setting_folds is None and set(FULL.variants) == set(VARIANTS)
    assert QUICK.seeds == (0,) and QUICK.n_setting_folds == 4
    assert get_schedule(TINY) is TINY


@pytest.mark.parametrize(
    "schedule, match",
    [
        ("medium", "medium"),
        (Schedule(name="x", variants=("PDL+GRU", "PDL+XYZ")), "PDL\\+XYZ"),
        (Schedule(name="x", seeds=()), "seed"),
    ],
)
def test_bad_schedule(schedule, match, data):
    with pytest.raises(ValueError, match=match):
        get_schedule(schedule)
    X, y = data
    with pytest.raises(ValueError, match=match):
        run_protocol(X, y, schedule=schedule)


def test_single_catheter_is_an_error(data):
    X, y = data
    one = (X["catheter"].astype(str) == "C1").to_numpy()
    with pytest.raises(ValueError, match="catheter"):
        run_protocol(X[one], y[one], schedule=TINY)


def test_missing_target_is_an_error(data):
    X, _ = data
    with pytest.raises(ValueError, match="y"):
        run_protocol(X, None, schedule=TINY)


def test_every_setting_excluded_is_an_error(data):
    X, y = data
    keep = X["setting"].astype(str).isin(["S00", "S01"]).to_numpy()
    with pytest.raises(ValueError, match="no setting to test"):
        run_protocol(X[keep], y[keep], schedule=TINY, exclude_settings=["S00", "S01"])


@pytest.mark.parametrize(
    "call, name",
    [
        (lambda r: compute_tables(r, n_bootstrap=0), "n_bootstrap"),
        (lambda r: run_protocol(r.X, r.y, schedule=TINY, n_jobs=1.5), "n_jobs"),
        (lambda r: write_results({}, "out", figures="yes"), "figures"),
    ],
)
def test_bad_parameters_name_the_parameter(call, name, result):
    with pytest.raises(InvalidParameterError, match=f"'{name}' parameter"):
        call(result)


# ---------------------------------------------------------------------------
# the method registry
# ---------------------------------------------------------------------------
def test_registry_describes_every_method_once():
    assert list(METHODS) == [
        "PCC", "PDL", "PDL+adapt", "PDL+GRU", "PDL+GRU+adapt", "PDL+MLP", "PDL+GRU (no torque)",
        "PDL+GRU (no context)", "PDL+GRU (no torque, no context)", "PDL+GRU (LOCO)",
        "PDL+GRU+adapt (LOCO)",
    ]
    assert all(name == method.name for name, method in METHODS.items())
    colours = [method.colour for method in METHODS.values()]
    assert len(set(colours)) == len(colours)
    # the learned methods trained within the catheter, with their learner and inputs
    assert dict(VARIANTS) == {
        "PDL+GRU": ("gru", True, True),
        "PDL+GRU+adapt": ("gru", True, True),
        "PDL+MLP": ("mlp", True, True),
        "PDL+GRU (no torque)": ("gru", False, True),
        "PDL+GRU (no context)": ("gru", True, False),
        "PDL+GRU (no torque, no context)": ("gru", False, False),
    }
    assert METHODS[LOCO_METHOD].loco and LOCO_METHOD not in VARIANTS
    assert dict(LOCO_METHODS) == {
        "PDL+GRU (LOCO)": "PDL+GRU", "PDL+GRU+adapt (LOCO)": "PDL+GRU+adapt",
    }
    # the adapted methods differ from their paper counterparts by the backbone only
    assert ADAPTED_METHOD == "PDL+GRU+adapt"
    assert [name for name, m in METHODS.items() if m.adapt] == [
        "PDL+adapt", "PDL+GRU+adapt", "PDL+GRU+adapt (LOCO)",
    ]
    assert METHODS["PDL+adapt"].backbone_params == {"hysteresis": "play"}
    assert METHODS["PDL"].backbone_params == {}
    assert [backbone_method(m) for m in ("PDL+GRU", "PDL+GRU+adapt (LOCO)", "PCC")] == [
        "PDL", "PDL+adapt", "PCC",
    ]
    assert PROPOSED_METHOD == "PDL+GRU" and FULL.variants == tuple(VARIANTS)
    # every role lists its methods at distinct positions 0, 1, ...
    for role in ROLES:
        positions = sorted(m.roles[role] for m in METHODS.values() if role in m.roles)
        assert positions == list(range(len(positions))), role


def test_tables_and_figures_read_their_methods_from_the_registry():
    assert MAIN_METHODS == methods_with_role("main") == ("PCC", "PDL", "PDL+GRU")
    assert methods_with_role("residual_learners") == ("PDL+MLP", "PDL+GRU")
    assert methods_with_role("loco") == ("PDL", "PDL+GRU", "PDL+GRU (LOCO)")
    assert methods_with_role("example") == ("PDL+GRU", "PDL")
    assert BUDGET_METHODS == ("PCC", "PDL", "PDL+GRU")
    assert dict(TORQUE_CONTEXT) == {
        ("No", "No"): "PDL+GRU (no torque, no context)",
        ("Yes", "No"): "PDL+GRU (no context)",
        ("No", "Yes"): "PDL+GRU (no torque)",
        ("Yes", "Yes"): "PDL+GRU",
    }
    assert dict(COMPARISONS) == {
        "PCC -> PDL+GRU": ("PCC", "PDL+GRU"),
        "PDL -> PDL+GRU": ("PDL", "PDL+GRU"),
        "PDL+MLP -> PDL+GRU": ("PDL+MLP", "PDL+GRU"),
        "torque (with context)": ("PDL+GRU (no torque)", "PDL+GRU"),
        "torque (without context)": ("PDL+GRU (no torque, no context)", "PDL+GRU (no context)"),
        "context (with torque)": ("PDL+GRU (no context)", "PDL+GRU"),
        "context (without torque)": ("PDL+GRU (no torque, no context)", "PDL+GRU (no torque)"),
        "catheter held out -> setting held out": ("PDL+GRU (LOCO)", "PDL+GRU"),
        "sweep adaptation (setting held out)": ("PDL+GRU", "PDL+GRU+adapt"),
        "sweep adaptation (catheter held out)": ("PDL+GRU (LOCO)", "PDL+GRU+adapt (LOCO)"),
    }
    from skcath.protocol import _figure_tools, _figures

    assert _figures.CONDITIONING_METHODS == (
        "PDL+GRU", "PDL+GRU (no torque)", "PDL+GRU (no context)", "PDL+GRU (no torque, no context)",
    )
    assert _figures.NEW_CATHETER_METHODS == ("PDL+GRU", "PDL+GRU (LOCO)")
    assert _figure_tools._method_colours(["PDL+MLP", "mine"]) == {"PDL+MLP": "tab:red", "mine": "tab:cyan"}
    with pytest.raises(InvalidParameterError, match="'role' parameter"):
        methods_with_role("table_9")


@pytest.mark.parametrize("method", list(VARIANTS))
def test_make_learner_builds_the_method(method):
    learner, use_torque, use_context = VARIANTS[method]
    model = make_learner(method, random_state=3, max_epochs=2)
    assert type(model).__name__ == {"gru": "GRUResidual", "mlp": "MLPResidual"}[learner]
    assert (model.use_torque, model.use_context) == (use_torque, use_context)
    assert (model.random_state, model.max_epochs) == (3, 2)


def test_make_learner_refuses_what_the_method_fixes():
    with pytest.raises(ValueError, match=r"sets \['use_context'\] itself"):
        make_learner("PDL+GRU", use_context=False)
    with pytest.raises(InvalidParameterError, match="'method' parameter"):
        make_learner("PDL")


# ---------------------------------------------------------------------------
# the protocol's steps
# ---------------------------------------------------------------------------
def test_protocol_folds(data):
    X, _ = data
    info = _run_table(X)
    folds = protocol_folds(X, TINY, exclude_settings=EXCLUDED)
    assert [fold.catheter for fold in folds.loco] == ["C1", "C2"]
    assert len(folds.within) == 2 * TINY.n_setting_folds
    for fold in folds.loco + folds.within:
        tested = set(info.loc[sorted(_runs(X.iloc[fold.test])), "catheter"])
        assert tested == {fold.catheter}
        assert EXCLUDED not in set(X["setting"].astype(str).iloc[fold.test])
    only = protocol_folds(X, TINY, exclude_settings=EXCLUDED, catheters=["C2"])
    assert [fold.catheter for fold in only.loco + only.within] == ["C2"] * 3
    assert_array_equal(only.loco[0].train, folds.loco[1].train)


def test_calibrate_backbones_gives_every_backbone_and_the_learner_input(data):
    X, _ = data
    runs = X["run"].isin(X["run"].iloc[[0, -1]]).to_numpy()  # one run of each catheter
    Xr = X[runs].reset_index(drop=True)
    inputs, predictions = calibrate_backbones(Xr)
    assert list(predictions) == ["PCC", "PDL", "PDL+adapt"]
    assert list(inputs) == ["PDL", "PDL+adapt"]
    assert all(tuple(X_learner.columns) == LEARNER_COLUMNS for X_learner in inputs.values())
    assert_allclose(predictions["PCC"], PCCBackbone().fit(Xr).predict(Xr), rtol=1e-9, atol=1e-9)
    assert_allclose(predictions["PDL"], PDLBackbone().fit(Xr).predict(Xr), rtol=1e-9, atol=1e-9)
    played = PDLBackbone(hysteresis="play").fit(Xr).predict(Xr)
    assert_allclose(predictions["PDL+adapt"], played, rtol=1e-9, atol=1e-9)
    for name, X_learner in inputs.items():
        assert_array_equal(X_learner[list(BACKBONE_COLUMNS)].to_numpy(), predictions[name])
    # the sweep adaptation changes the nominal tip, not the rest of the learner input
    pd.testing.assert_frame_equal(inputs["PDL"].drop(columns=list(BACKBONE_COLUMNS)),
                                  inputs["PDL+adapt"].drop(columns=list(BACKBONE_COLUMNS)))
    assert not np.allclose(predictions["PDL"], predictions["PDL+adapt"])
    only, _ = calibrate_backbones(Xr, methods=["PDL"])
    assert list(only) == ["PDL"]
    pd.testing.assert_frame_equal(only["PDL"], inputs["PDL"])
