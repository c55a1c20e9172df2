from madp.models.bench import bench_infer, bench_train_step


def test_bench_functions_report():
    r = bench_train_step("madp", "cpu", batch_size=2, num_robots=4, steps=1, warmup=0, measure_matmul=False)
    assert r["samples_per_s"] > 0 and r["flops_per_step"] > 0
    r = bench_train_step("lpac", "cpu", batch_size=2, num_robots=4, steps=1, warmup=0)
    assert r["samples_per_s"] > 0
    r = bench_infer("cpu", "decentralized", num_steps=2, num_robots=4, repeats=1, warmup=0)
    assert r["latency_s"] > 0 and r["max_neighbourhood"] >= 1
