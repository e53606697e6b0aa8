"""``sdi.separate`` mapped over several recordings with Dask's
``distributed.LocalCluster``: one task per file, each worker a process
(``sdi.separate`` releases the GIL, so threads would do as well).

    python python/examples/dask_separate.py [METHOD] FILE...

FILEs are .sdirec recordings or .npy stacks (N, H, W) of DN. Prints the
throughput with 1 and 2 workers.
"""

import sys
import time

import numpy as np

import sdi


def load(path):
    """A stack of dark-subtracted frames from a recording or an .npy."""
    if str(path).endswith(".sdirec"):
        return sdi.read_recording(path).read()
    return np.load(path)


def separate_file(path, method):
    """One task: the file's I+ and I- (electrons), and how many frames it held."""
    stack = load(path)
    return sdi.separate(stack, method).estimate, len(stack)


def separate_all(paths, method, workers):
    """Separates every file on a LocalCluster of `workers` processes;
    returns the estimates (in the files' order), frames and seconds."""
    from distributed import Client, LocalCluster

    with LocalCluster(n_workers=workers, threads_per_worker=1, processes=True,
                      dashboard_address=None) as cluster, Client(cluster) as client:
        client.submit(sdi.modes).result()  # workers up, sdi imported
        t0 = time.perf_counter()
        futures = client.map(separate_file, paths, method=method, pure=False)
        results = client.gather(futures)
        seconds = time.perf_counter() - t0
    return [r[0] for r in results], sum(r[1] for r in results), seconds


def main():
    args = sys.argv[1:]
    method = "m3"
    if args and not args[0].endswith((".npy", ".sdirec")):
        method = args.pop(0)
    for workers in (1, 2):
        _, frames, seconds = separate_all(args, method, workers)
        print(f"{workers} worker(s): {len(args)} files, {frames} frames by {method} "
              f"in {seconds:.2f} s = {frames / seconds:.1f} frames/s")


if __name__ == "__main__":
    main()
