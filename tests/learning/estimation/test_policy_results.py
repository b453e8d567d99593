"""benchmarks/nfpde_policy.py's results file, shared by processes that train on different
estimates (one per sampler, run side by side): each keeps the others' runs and estimates."""

import json


def test_processes_sharing_a_results_file_keep_each_others_runs_and_estimates(tmp_path, benchmark_script):
    merge = benchmark_script("nfpde_policy").merge_with_file
    path = tmp_path / "nfpde_policy-humanoid-mixture5.json"
    run = lambda name, seed: {"algo": "sac", "train_on": name, "seed": seed, "final_mean_return": 1.0}  # noqa: E731
    # the DROPO process wrote first; the NFPDE process read the file before that
    path.write_text(
        json.dumps(
            {
                "runs": [run("dropo", 0)],
                "commands": ["b"],
                "estimates": {"dropo": {"ot": 1.4, "seconds": 185.0, "sim_calls": 98304}},
            }
        )
    )
    doc = {
        "runs": [run("nfpde-softmax", 0), run("nfpde-softmax", 0)],
        "commands": ["a", "a"],
        "estimates": {"nfpde-softmax": {"ot": 0.88}},
    }
    merge(path, doc)
    assert sorted((r["train_on"], r["seed"]) for r in doc["runs"]) == [("dropo", 0), ("nfpde-softmax", 0)]
    assert doc["commands"] == ["b", "a"]
    assert doc["estimates"] == {
        "dropo": {"ot": 1.4, "seconds": 185.0, "sim_calls": 98304},
        "nfpde-softmax": {"ot": 0.88},
    }
    # this process's own record wins over the file's
    doc["estimates"]["dropo"]["ot"] = 1.5
    merge(path, doc)
    assert doc["estimates"]["dropo"]["ot"] == 1.5
