"""Timing shared by the Python references of the side-by-side benches."""
import time


def median_ms(fn, reps):
    """(median wall ms, mean thread CPU ms) per call of `fn` over `reps` calls."""
    times = []
    c0 = time.thread_time()
    for _ in range(reps):
        t0 = time.perf_counter()
        fn()
        times.append((time.perf_counter() - t0) * 1e3)
    cpu = (time.thread_time() - c0) * 1e3 / reps
    times.sort()
    return times[len(times) // 2], cpu
