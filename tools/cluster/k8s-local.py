#!/usr/bin/env python3
"""Run the Jobs of Kubernetes manifests on this machine, pod by pod, as the Job controller
would start them, with no cluster: a check of the recipes in tools/cluster/ (detect-k8s.yaml
and detect-k8s-merge.yaml), not a scheduler.

    tools/cluster/k8s-local.py [--volume CLAIM=DIR ...] [--validate VERSION] MANIFEST ...

For each Job, in the order given: `completions` pods (1 unless set), each running its
containers' `command` (+ `args`) as a process, at most `parallelism` at a time. What is
emulated, as Kubernetes specifies it:

- an Indexed Job (`completionMode: Indexed`) gives pod i the environment variable
  JOB_COMPLETION_INDEX=i;
- `$(NAME)` in a command or argument is replaced by the container's environment variable NAME
  (from `env` values and JOB_COMPLETION_INDEX), `$$` by `$`, and anything else is left as is;
- a volume from a persistentVolumeClaim is the local directory given for its claim with
  `--volume CLAIM=DIR`: a command's paths under the volume's `mountPath` are rewritten to DIR
  (the only change made to a command).

The programs named by the commands are found on the PATH (put photonkit's directory on it).
A Job fails when any of its pods exits non-zero; the script then stops with that status.
`--validate VERSION` first checks every manifest against that Kubernetes version's API schema,
strictly (no unknown fields), with the `kubernetes-validate` package from PyPI.
"""

import argparse
import os
import re
import subprocess
import sys
from concurrent.futures import ThreadPoolExecutor

import yaml


def expand(text, env):
    """Kubernetes' $(NAME) expansion of a command or argument."""
    return re.sub(r"\$\$|\$\(([A-Za-z_][A-Za-z0-9_]*)\)",
                  lambda m: "$" if m.group(0) == "$$" else env.get(m.group(1), m.group(0)), text)


def container_command(container, env, mounts):
    words = [expand(w, env) for w in container.get("command", []) + container.get("args", [])]
    for mount_path, local in mounts:
        words = [w.replace(mount_path.rstrip("/") + "/", local.rstrip("/") + "/") for w in words]
    if not words:
        sys.exit(f"k8s-local: container {container.get('name')} has no command (the image's "
                 "entrypoint is not known here)")
    return words


def run_job(job, claims):
    spec = job["spec"]
    name = job["metadata"]["name"]
    pod = spec["template"]["spec"]
    volumes = {}
    for v in pod.get("volumes", []):
        claim = v.get("persistentVolumeClaim", {}).get("claimName")
        if claim is None:
            sys.exit(f"k8s-local: job {name}: volume {v['name']} is not a persistentVolumeClaim")
        if claim not in claims:
            sys.exit(f"k8s-local: job {name}: give the claim's directory with --volume {claim}=DIR")
        volumes[v["name"]] = claims[claim]
    completions = spec.get("completions", 1)
    parallelism = spec.get("parallelism", 1)
    indexed = spec.get("completionMode", "NonIndexed") == "Indexed"

    def run_pod(i):
        for c in pod.get("initContainers", []) + pod["containers"]:
            env = {e["name"]: str(e.get("value", "")) for e in c.get("env", [])}
            if indexed:
                env["JOB_COMPLETION_INDEX"] = str(i)
            mounts = [(m["mountPath"], volumes[m["name"]]) for m in c.get("volumeMounts", [])]
            words = container_command(c, env, mounts)
            status = subprocess.run(words, env={**os.environ, **env}).returncode
            if status != 0:
                return i, status
        return i, 0

    with ThreadPoolExecutor(max_workers=max(1, parallelism)) as pool:
        failed = [(i, s) for i, s in pool.map(run_pod, range(completions)) if s != 0]
    if failed:
        i, s = failed[0]
        sys.exit(f"k8s-local: job {name}: pod {i} exited with status {s}")
    print(f"k8s-local: job {name}: {completions} pod(s) completed", file=sys.stderr)


def main():
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--volume", action="append", default=[], metavar="CLAIM=DIR")
    ap.add_argument("--validate", metavar="VERSION")
    ap.add_argument("manifests", nargs="+")
    a = ap.parse_args()
    claims = dict(v.split("=", 1) for v in a.volume)
    docs = []
    for path in a.manifests:
        with open(path) as f:
            docs += [d for d in yaml.safe_load_all(f) if d]
    if a.validate:
        import kubernetes_validate

        for d in docs:
            try:
                kubernetes_validate.validate(d, a.validate, strict=True)
            except kubernetes_validate.ValidationError as e:
                sys.exit(f"k8s-local: {d['kind']} {d['metadata']['name']} is not valid for Kubernetes "
                         f"{a.validate}: {e.message}")
    for d in docs:
        if d.get("kind") != "Job":
            sys.exit(f"k8s-local: only Jobs are run, not {d.get('kind')}")
        run_job(d, claims)


if __name__ == "__main__":
    main()
