"""bench-scb on a coarse scene: the parts it reports add up to the run it timed."""
import argparse


def test_bench_scb_accounts_for_the_whole_run(tmp_path):
    from upscale.experiments.scenes.scb import SCBScene
    from validation.cases.bench_scb import bench_scb, direct_solve_time

    args = argparse.Namespace(quick=True, dx=3e-3, alphas="0", r_s=3e-3, stop_fraction=0.1, u_max=2e-2,
                              max_equilibria=400, profile=True, outdir=tmp_path)
    res = bench_scb(args)
    assert res["full_crack"] and res["stop_reason"] == ["load dropped"]
    assert res["final_over_peak"][0] < 0.1 and res["crack_reach_y_over_R"][0] > 0.8
    shares = res["time_share_pct"]
    assert abs(sum(shares.values()) - 100.0) < 1e-9 and min(v for k, v in shares.items() if k != "other") >= 0
    assert res["profile"] and res["table_wall_s"] == sum(res["wall_s_per_angle"])
    assert (tmp_path / "bench-scb_partial.json").exists()
    sc = SCBScene(0.0, dx=3e-3, r_s=3e-3)
    t, nfree, nnz = direct_solve_time(sc)
    assert t > 0 and nfree == 2 * sc.system.n - int(sc.fixed[:, :2].sum()) and nnz > nfree
