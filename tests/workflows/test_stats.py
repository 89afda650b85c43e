"""Honest Monte-Carlo statistics (softsbi.workflows.stats): p-values, max-T, adaptive resolution."""
import numpy as np
import pytest

from softsbi.core.errors import SoftsbiError
from softsbi.workflows.stats import (MCPValue, decided, max_t_adjusted, mc_pvalue, misspecification_test,
                                     resolution_needed)


def test_monte_carlo_p_value_counts_and_never_goes_below_its_resolution():
    null = np.arange(30, dtype=float)
    p = mc_pvalue(26.5, null)  # 27, 28, 29 are as extreme
    assert (p.exceed, p.n) == (3, 30) and p.value == pytest.approx(4 / 31)
    assert p.text() == "p = 0.13 (3 of 30 null simulations as extreme)"
    far = mc_pvalue(1e9, null)
    assert far.value == pytest.approx(1 / 31) == far.floor and far.at_floor
    assert far.text() == "p <= 1/31 (beyond all 30 null simulations)"
    assert mc_pvalue(29.0, null).exceed == 1  # ties count as extreme
    with pytest.raises(SoftsbiError, match="non-finite"):
        mc_pvalue(np.nan, null)
    with pytest.raises(SoftsbiError, match="at least one"):
        mc_pvalue(1.0, [])


def test_misspecification_test_is_calibrated_and_floored():
    rng = np.random.default_rng(0)
    sims = rng.normal(size=(40, 30))
    inside = misspecification_test(rng.normal(size=30), sims)
    outside = misspecification_test(rng.normal(size=30) + 3.0, sims)
    assert inside["p_value"] > 0.05
    assert outside["exceed"] == 0 and outside["p_value"] == pytest.approx(1 / 41)
    assert outside["statistic"] > 5 * inside["statistic"] and "beyond all 40" in outside["p_text"]
    # under the null the p-value is (close to) uniform: rejections at 0.1 about 10% of the time
    rej = [misspecification_test(rng.normal(size=30), rng.normal(size=(19, 30)))["p_value"] <= 0.1
           for _ in range(300)]
    assert abs(np.mean(rej) - 0.1) < 3 * np.sqrt(0.1 * 0.9 / 300)


def _correlated(rng, n, C, rho=0.6):
    common = rng.normal(size=(n, 1))
    return np.sqrt(rho) * common + np.sqrt(1 - rho) * rng.normal(size=(n, C))


def test_max_t_controls_the_family_wise_error_and_beats_bonferroni_at_low_resolution():
    rng = np.random.default_rng(1)
    C, n, alpha, reps = 5, 39, 0.05, 1500
    fwe = 0
    for _ in range(reps):
        x = _correlated(rng, n + 1, C) ** 2  # chi-square-like drops, dependent across candidates
        adj, _ = max_t_adjusted(x[0], x[1:])
        fwe += min(p.value for p in adj) <= alpha
    rate = fwe / reps
    assert rate <= alpha + 3 * np.sqrt(alpha * (1 - alpha) / reps)
    assert rate > alpha / 3  # and not absurdly conservative
    # adjusted p-values are never below the marginal ones
    x = _correlated(rng, n + 1, C) ** 2
    adj, z = max_t_adjusted(x[0], x[1:])
    for c in range(C):
        assert adj[c].value >= mc_pvalue(x[0, c], x[1:, c]).value
    # one strong candidate among five with 30 nulls: max-T can reach 1/31 < 0.05, Bonferroni needs
    # a marginal p <= 0.01 that 30 nulls cannot give
    null = _correlated(rng, 30, C) ** 2
    obs = null.mean(0).copy()
    obs[2] = 50.0
    adj, z = max_t_adjusted(obs, null)
    assert adj[2].value == pytest.approx(1 / 31) and adj[2].value <= alpha
    assert mc_pvalue(obs[2], null[:, 2]).value > alpha / C
    assert all(adj[c].value > alpha for c in (0, 1, 3, 4)) and np.argmax(z) == 2
    with pytest.raises(SoftsbiError, match="shape"):
        max_t_adjusted(obs, null[:, :3])


def test_adaptive_resolution_extends_only_when_promising_and_keeps_the_level():
    assert resolution_needed(MCPValue(0, 30), 0.01, 200)
    assert resolution_needed(MCPValue(1, 30), 0.01, 200)  # 2/201 <= 0.01: the cap can still decide
    assert not resolution_needed(MCPValue(1, 30), 0.01, 120, promising=0)  # 2/121 > 0.01 and no eager rule
    assert resolution_needed(MCPValue(2, 30), 0.005, 200)  # 3/201 > 0.005, but the first stage's 3/31 <= 0.1
    assert not resolution_needed(MCPValue(3, 30), 0.005, 200)  # 4/31 > 0.1 and 4/201 > 0.005
    assert not resolution_needed(MCPValue(0, 199), 0.01, 300)  # 1/200 <= 0.01: already decidable
    assert not resolution_needed(MCPValue(0, 200), 0.01, 200)
    # the two-stage test under the null: reject at most alpha of the time
    rng = np.random.default_rng(2)
    alpha, n1, cap, reps = 0.02, 30, 99, 4000
    rej = 0
    for _ in range(reps):
        x = rng.normal(size=cap + 1)
        p = mc_pvalue(x[0], x[1:n1 + 1])
        if resolution_needed(p, alpha, cap):
            p = mc_pvalue(x[0], x[1:])
        rej += p.value <= alpha
    assert rej / reps <= alpha + 3 * np.sqrt(alpha * (1 - alpha) / reps)
    # the rule as applied names the resolution, and the fix when the cap is too small
    t = decided({"exceed": 0, "n_null": 50, "p_value": 1 / 51}, 0.01, 50, True, "misfit")
    assert not t["misspecified"] and "p <= 1/51" in t["rule"] and "raise the cap" in t["rule"]
    t = decided({"exceed": 0, "n_null": 200, "p_value": 1 / 201}, 0.01, 200, True, "misfit")
    assert t["misspecified"] and t["rule"].endswith("<= 0.01")


def test_a_first_stage_decision_inside_its_monte_carlo_error_is_not_resolved():
    """resolved_side: the exact 90% interval of the exceedance probability against the level. At rule 3's 0.1
    per test, 0 of 30 is resolved below, 1-6 of 30 are not, 7 of 30 is resolved above; at the verdicts' 0.025
    per test the unresolved counts (0-2) are the ones EXTEND_P already extends, so nothing changes there."""
    from softsbi.workflows.screening import joint_resolved
    from softsbi.workflows.stats import EXTEND_P, resolved_side
    assert resolved_side(MCPValue(0, 30), 0.1) == "below"
    assert [resolved_side(MCPValue(k, 30), 0.1) for k in range(1, 7)] == [None] * 6
    assert resolved_side(MCPValue(7, 30), 0.1) == "above"
    assert resolved_side(MCPValue(10, 200), 0.1) == "below" and resolved_side(MCPValue(19, 200), 0.1) is None
    for k in range(0, 31):
        unresolved_at_verdict_level = not joint_resolved([MCPValue(k, 30), MCPValue(30, 30)], 0.025)
        assert unresolved_at_verdict_level == (MCPValue(k, 30).value <= EXTEND_P)
    # Bonferroni: one test resolved below rejects whatever the other; accepting needs both resolved above
    assert joint_resolved([MCPValue(0, 30), MCPValue(3, 30)], 0.1)
    assert not joint_resolved([MCPValue(10, 30), MCPValue(3, 30)], 0.1)
    assert joint_resolved([MCPValue(10, 30), MCPValue(12, 30)], 0.1)
    with pytest.raises(ValueError, match="level"):
        resolved_side(MCPValue(0, 30), 1.5)
    # a first-stage decision is wrong (the side of the true exceedance probability) at most about 1 - 0.9 of
    # the times it is taken, for true probabilities on either side of the level
    rng = np.random.default_rng(3)
    for q in (0.03, 0.06, 0.14, 0.2):
        k = rng.binomial(30, q, size=4000)
        sides = [resolved_side(MCPValue(int(x), 30), 0.1) for x in k]
        taken = [s for s in sides if s is not None]
        wrong = sum(s != ("below" if q < 0.1 else "above") for s in taken)
        assert wrong <= 0.1 * len(sides)


def test_the_null_grows_when_a_lenient_levels_first_stage_is_unresolved(monkeypatch):
    """misspecification_verdict at rule 3's 0.2: 4 exceedances in 30 (p = 0.16, 90% interval 0.05-0.28) is inside
    its Monte-Carlo error, so the null grows to the cap and the decision is taken there; 0 or 12 in 30 is decided
    at 30, and so is 12 in 30 at 0.05."""
    from softsbi.workflows import screening as scr

    class Pool:
        def __init__(self):
            self.rollouts, self.requested, self.first, self.run = [None] * 30, 30, 30, type("R", (), {"dense": None})()

        @property
        def features(self):
            return np.zeros((len(self.rollouts), 2))

        def ensure_successful(self, n):
            self.rollouts, self.requested = [None] * n, n
            return self

    def verdict(rate_at, alpha):
        def test(f_obs, feats):
            n = len(feats)
            return {"statistic": 1.0, "null_mean": 0.5, "null_q95": 1.2, "exceed": rate_at(n), "n_simulations": n}
        monkeypatch.setattr(scr, "misspecification_test", test)
        monkeypatch.setattr(scr, "run_features", lambda run, dense: np.zeros(2))
        return scr.misspecification_verdict(Pool(), [], alpha, 200)[0]

    grown = verdict(lambda n: 4 if n == 30 else 60, 0.2)  # 4/30 first, then 60/200: accepted at the cap
    assert grown["extended"] and grown["n_null"] == 200 and not grown["misspecified"]
    assert grown["p_value"] == pytest.approx(61 / 201) and "200 null simulations" in grown["p_text"]
    for k in (0, 12):
        t = verdict(lambda n, k=k: k, 0.2)
        assert not t["extended"] and t["n_null"] == 30 and t["misspecified"] == (k == 0)
    t = verdict(lambda n: 12, 0.05)  # 90% interval 0.25-0.56, far above 0.05: nothing more is simulated
    assert not t["extended"] and not t["misspecified"]


def _screening(r_obs, r_null, cols, generic=()):
    """A screening on synthetic residuals: effect ``name`` adds ``coef * cols[name]`` (coef >= 0)."""
    from softsbi.core.interfaces import Effect
    from softsbi.core.types import Param, ParamSpace
    from softsbi.workflows.screening import Screening

    def effect(nm):
        return type(nm, (Effect,), {"name": nm, "description": nm, "generic": nm in generic,
                                    "kind": "sensor" if nm == "B" else "physics",
                                    "param_space": lambda self: ParamSpace([Param("k", 0.0, 10.0, "")])})()
    sc = Screening.__new__(Screening)
    rng = np.random.default_rng(5)
    sc.J_theta = rng.normal(size=(len(r_obs), 2))
    sc.r_obs, sc.r_null, sc.failed = r_obs, r_null, []
    sc.design = {nm: {"effect": effect(nm), "J": c[:, None], "offset": np.zeros(len(r_obs)), "lo": np.array([0.0]),
                      "hi": np.array([10.0]), "steps": [("k", 0.0, 0.1)]} for nm, c in cols.items()}
    return sc


def test_forward_selection_names_two_effects_and_leaves_a_generic_term_unnamed():
    rng = np.random.default_rng(4)
    F = 60
    cols = {n: rng.normal(size=F) for n in ("A", "B", "C")}
    null = rng.normal(size=(60, F))
    # two effects present: both named, the stronger first, each with the max-T rule as applied
    sc = _screening(rng.normal(size=F) + 1.2 * cols["A"] + 0.8 * cols["B"], null, cols, generic=("C",))
    ranking = sc.ranking()
    chosen, log = sc.forward_selection(ranking, 0.05, 0.1)
    assert chosen == ["A", "B"] and [st["accepted"] for st in log] == [True, True]  # C is generic: not named
    assert log[1]["given"] == ["A"] and ranking[0]["effect"] == "A" and ranking[0]["kind"] == "physics"
    assert next(r for r in ranking if r["effect"] == "B")["kind"] == "sensor"
    assert ranking[0]["estimate"]["k"] == pytest.approx(1.2, abs=0.3)
    assert all(r["adjusted_p_value"] >= 1 / 61 for r in ranking)
    # only the generic term explains it: nothing named, the generic term ranks first
    sc = _screening(rng.normal(size=F) + 1.5 * cols["C"], null, cols, generic=("C",))
    ranking = sc.ranking()
    chosen, log = sc.forward_selection(ranking, 0.05, 0.1)
    assert chosen == [] and ranking[0]["effect"] == "C" and ranking[0]["generic"]
    assert ranking[0]["adjusted_p_value"] <= 0.05 and not log[0]["accepted"]
    # pure noise: nothing passes
    sc = _screening(rng.normal(size=F), null, cols)
    chosen, _ = sc.forward_selection(sc.ranking(), 0.05, 0.1)
    assert chosen == []


def test_forward_selection_takes_the_strongest_candidate_that_passes_not_the_first_ranked():
    """Rule 2 among the candidates that pass it: a first-ranked candidate that explains too little (it won the
    ordering on its normalised statistic) is passed over, and the selection goes on to the one that passes
    (fresh benchmark case mujoco-more 656: point noise first with 2%, time offset 66%, both at adjusted p = 2/201)."""
    from softsbi.workflows.diagnose import decision_rules
    sc = _screening(np.zeros(4), np.zeros((3, 4)), {"A": np.ones(4), "B": np.ones(4)})
    ranking = [{"effect": "A", "generic": False, "statistic": 1.0, "adjusted_p_value": 0.01, "adjusted_p_text": "p",
                "explained_fraction": 0.02},
               {"effect": "B", "generic": False, "statistic": 9.0, "adjusted_p_value": 0.01, "adjusted_p_text": "p",
                "explained_fraction": 0.66}]
    sc.family = lambda names, given: [r for r in ranking if r["effect"] in names]  # step 2: nothing else passes
    chosen, log = sc.forward_selection(ranking, 0.05, 0.1)
    assert chosen == ["B"]
    assert log[0]["best"] == "B" and log[0]["accepted"] and log[0]["passed_over"] == ["A"]
    assert log[1]["best"] == "A" and not log[1]["accepted"] and log[1]["passed_over"] == []
    rules = decision_rules({"alpha": 0.05, "min_explained": 0.1, "selection": log,
                            "misspecification": {"misspecified": True, "p_text": "p = 0.01"}})
    assert "B has p, explains 66% -> accepted (ranked above it but failing the rule: A)" in rules[1]
    # none passes: the strongest named candidate is reported, rejected, nothing chosen
    ranking[1]["explained_fraction"] = 0.05
    chosen, log = sc.forward_selection(ranking, 0.05, 0.1)
    assert chosen == [] and log == [{**log[0], "best": "A", "accepted": False, "passed_over": []}]


def test_the_rule_asks_for_more_nulls_only_when_resolution_decides():
    from softsbi.workflows.stats import decided
    beyond = decided({"exceed": 0, "n_null": 30}, 0.01, 30, False, "misspecified")
    assert not beyond["misspecified"] and "raise the cap (--max-null) to at least 99" in beyond["rule"]
    # 3 of 30 as extreme (p = 0.13): more nulls would not bring it to 0.01; no advice
    some = decided({"exceed": 3, "n_null": 30}, 0.01, 30, False, "misspecified")
    assert not some["misspecified"] and "raise the cap" not in some["rule"]
    assert decided({"exceed": 0, "n_null": 200}, 0.01, 200, True, "misspecified")["misspecified"]


def test_a_near_miss_at_the_cap_is_told_how_more_nulls_could_decide_it():
    """1 of 200 nulls as extreme (joint p = 0.02 > 0.01): at a cap of 400 the test could still reject (2/401 <=
    0.005), so the rule says how; 2 of 200 could not (3/401 > 0.005), and the rule stays silent."""
    from softsbi.workflows.screening import near_miss_advice
    from softsbi.workflows.stats import MCPValue
    one = near_miss_advice([("omnibus", MCPValue(40, 200)), ("directional", MCPValue(1, 200))], 0.01, 200)
    assert one.startswith("; 1 of 200 nulls are as extreme in the directional test") and \
        "with --max-null 400 it rejects if at most 1 of 400 are" in one
    assert (1 + 1) / 401 <= 0.01 / 2 < (2 + 1) / 401  # the advice's arithmetic: at most 1 of 400
    assert near_miss_advice([("omnibus", MCPValue(2, 200)), ("directional", MCPValue(5, 200))], 0.01, 200) == ""
    # the omnibus test alone (k = 1): 2 of 200 still fit under 0.01 at 400 (3/401), 4 do not (5/401)
    assert "at most 3 of 400" in near_miss_advice([("omnibus", MCPValue(2, 200))], 0.01, 200)
    assert near_miss_advice([("omnibus", MCPValue(4, 200))], 0.01, 200) == ""
    # not at the cap yet (30 nulls): the adaptive extension decides, not the user
    assert near_miss_advice([("omnibus", MCPValue(1, 30))], 0.01, 200) == ""


def test_the_joint_test_is_bonferroni_over_two_monte_carlo_p_values_and_keeps_its_level():
    """check's test: the omnibus and the directional test on one null, joint p = 2 x the smaller one,
    never below its resolution 2/(n + 1); under the null it rejects at most at its level, whatever the
    dependence of the two statistics."""
    from softsbi.workflows.screening import joint_decision
    from softsbi.workflows.stats import MCPValue, mc_pvalue
    j = joint_decision(MCPValue(0, 200), MCPValue(30, 200), 0.01)
    assert j["p_value"] == pytest.approx(2 / 201) and j["at_floor"] and j["tests"] == 2
    assert j["deciding_test"] == "omnibus" and j["p_text"].startswith("p <= 2/201 (two tests, Bonferroni; the omnibus")
    j = joint_decision(MCPValue(12, 200), MCPValue(3, 200), 0.01)
    assert j["p_value"] == pytest.approx(8 / 201) and j["deciding_test"] == "directional" and not j["at_floor"]
    assert "2 x the directional test's p = 0.02" in j["p_text"] and "200 null simulations" in j["p_text"]
    assert joint_decision(MCPValue(20, 30), MCPValue(25, 30), 0.01)["p_value"] == 1.0  # capped at 1
    one = joint_decision(MCPValue(5, 30), None, 0.01)  # no candidate screened: the omnibus test alone
    assert one["tests"] == 1 and one["p_value"] == pytest.approx(6 / 31) and one["resolution"] == pytest.approx(1 / 31)
    # level under the null: observation and 40 nulls exchangeable, two strongly dependent statistics
    rng = np.random.default_rng(11)
    rej = 0
    reps = 3000
    for _ in range(reps):
        x = rng.normal(size=41)
        s1, s2 = x, 0.8 * x + 0.6 * rng.normal(size=41)
        p1, p2 = mc_pvalue(s1[0], s1[1:]), mc_pvalue(s2[0], s2[1:])
        rej += joint_decision(p1, p2, 0.1)["p_value"] <= 0.1
    rate = rej / reps
    assert rate <= 0.1 + 2 * np.sqrt(0.1 * 0.9 / reps)
    assert rate >= 0.05  # not vacuous: dependent tests lose little to Bonferroni here


def test_a_null_grown_to_its_cap_counts_successful_rollouts():
    """Failed posterior-predictive rollouts do not cost resolution: the cap is reached in successes (an
    other-engine fling with 193 successes of 200 could not resolve the joint test's 2/201 <= 0.01), within a
    bound on requests when most fail."""
    from softsbi.workflows.stats import PosteriorPredictive

    class Flaky(PosteriorPredictive):
        def __init__(self, fail_every):
            self.rollouts, self.requested, self.first, self.fail_every = [], 0, 0, fail_every

        def ensure(self, n):
            for i in range(self.requested, n):
                if i % self.fail_every:
                    self.rollouts.append({"sample": i})
            self.first = self.first or n
            self.requested = max(n, self.requested)
            return self

    pool = Flaky(10).ensure(30)
    assert len(pool.rollouts) == 27
    pool.ensure_successful(200)
    assert len(pool.rollouts) == 200 and pool.requested == 223
    always = Flaky(1).ensure(30)  # every rollout fails: stops at twice the cap
    always.ensure_successful(200)
    assert always.requested == 400 and always.rollouts == []


def test_summary_bias_ignores_spread_and_follows_the_mean():
    """summary_bias estimates the squared standardised distance of the posterior predictive's mean summaries
    from the measurement's without bias: a pool that only widens (3x the spread, same mean) keeps it, a pool
    whose mean moves half-way to the measurement quarters it. Without the noise correction the widened pool
    would look farther away (its sample mean is noisier), and a refit that moved nothing would look worse."""
    from softsbi.workflows.stats import summary_bias

    rng = np.random.default_rng(3)
    F, S = 400, 30
    scale = np.full(F, 0.01)
    mu = np.zeros(F)
    mu[:50] = 0.01  # ||mu / scale||^2 = 50
    y = np.zeros(F)
    nominal = summary_bias(y, mu + rng.normal(0, 0.01, (S, F)), scale)
    widened = [summary_bias(y, mu + rng.normal(0, 0.03, (S, F)), scale, n_boot=100, seed=i) for i in range(8)]
    moved = summary_bias(y, 0.5 * mu + rng.normal(0, 0.01, (S, F)), scale)
    assert abs(nominal["b2"] - 50) < 3 * nominal["se"]
    b_wide = np.mean([w["b2"] for w in widened])
    se_wide = np.sqrt(np.mean([w["se"] ** 2 for w in widened]) / len(widened))
    assert abs(b_wide - 50) < 3 * se_wide
    assert abs(moved["b2"] - 12.5) < 3 * moved["se"]
    # the uncorrected distance of the widened pool's mean: about 50 + F * 9 / S = 170
    z = (mu + rng.normal(0, 0.03, (S, F)) - y) / scale
    assert float(z.mean(0) @ z.mean(0)) > 120
    assert nominal["n"] == S and len(nominal["scale"]) == F
    with pytest.raises(SoftsbiError, match="at least 5 simulations"):
        summary_bias(y, mu[None].repeat(4, 0), scale)


def _sheet(n: int = 12, size: float = 0.3) -> tuple[np.ndarray, np.ndarray]:
    """A flat square sheet ``(n * n, 3)`` m at height 0.2 m and its triangles."""
    u = np.linspace(0, size, n)
    xx, yy = np.meshgrid(u, u)
    v = np.stack([xx.ravel(), yy.ravel(), np.full(n * n, 0.2)], 1)
    f = [(i * n + j, i * n + j + 1, (i + 1) * n + j) for i in range(n - 1) for j in range(n - 1)]
    f += [(i * n + j + 1, (i + 1) * n + j + 1, (i + 1) * n + j) for i in range(n - 1) for j in range(n - 1)]
    return v, np.array(f)


def test_the_energy_score_is_smallest_at_the_measurements_own_noise_where_the_chamfer_is_not():
    """A measurement with 1 cm point noise on the observed surface; models that predict noise of 0, 1 and 2 cm.
    The posterior-predictive Chamfer is smallest for the noise-free model (it rewards predicting no spread), so
    the right sensor model raises it; the energy score (proper) is smallest at the measurement's own noise."""
    from types import SimpleNamespace

    from softsbi.perception.pointcloud import sensor_chamfer_per_frame
    from softsbi.workflows.stats import energy_score, sampled_points

    v, f = _sheet()
    T, P, S, sigma = 3, 300, 30, 0.01
    rng = np.random.default_rng(0)
    verts = np.repeat(v[None], T, 0)
    y = sampled_points(verts + rng.normal(0, sigma, verts.shape), f, P, 999)
    run = SimpleNamespace(post_theta=np.zeros(S), dense=y, metric_frames=None, metric_min_z=None, config={})

    def pool(noise: float, n: int = S) -> SimpleNamespace:
        ro = []
        for i in range(n):
            vv = verts + rng.normal(0, noise, verts.shape)
            ch = sensor_chamfer_per_frame(sampled_points(vv, f, P, 5000 + i), y)[0]
            ro.append({"vertices": vv, "faces": f, "chamfer": ch, "sample": i})
        return SimpleNamespace(run=run, rollouts=ro, energy_scores={})

    none, right, double = (energy_score(pool(s)) for s in (0.0, sigma, 2 * sigma))
    assert none["chamfer_m"] < right["chamfer_m"] < double["chamfer_m"]
    assert right["energy_m"] < none["energy_m"] - 5 * np.hypot(right["energy_se_m"], none["energy_se_m"])
    assert right["energy_m"] < double["energy_m"] - 5 * np.hypot(right["energy_se_m"], double["energy_se_m"])
    for e in (none, right, double):
        assert e["energy_m"] == pytest.approx(e["chamfer_m"] - e["spread_m"] / 2)
        assert e["n"] == S and e["pairs"] == 3 * S and 0 < e["energy_se_m"] < 0.1 * e["energy_m"]
    assert energy_score(pool(sigma, 2)) is None  # no spread from fewer than 3 rollouts
    # a pool shared by check and diagnose is scored once: the second call reads what the first stored
    p = pool(sigma)
    first = energy_score(p)
    for r in p.rollouts:
        r["chamfer"] = np.zeros_like(r["chamfer"])  # a recomputation would now give another Chamfer term
    assert energy_score(p) == first
