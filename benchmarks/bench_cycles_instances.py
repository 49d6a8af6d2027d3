"""What an instance costs Cycles: the memory a render adds per instanced object.

The L-system panel and the CLI's `lsystem` report say what flattening a grammar
into Cycles instances would cost (engine/lsystem_stats.py,
CYCLES_BYTES_PER_INSTANCE). Cycles makes one scene object per depsgraph
instance, so the cost grows with the instance count. This measures it: a
low-poly sphere instanced on the vertices of a grid mesh (N instances), rendered
by Cycles at 32 x 32, 1 sample, 1 thread, each N in a fresh process; the peak
resident memory the render adds, and the slope between the two largest N.

    .venv/bin/python -m benchmarks.bench_cycles_instances      # about 1 minute on 2 cores

Writes benchmarks/charts/cycles_instances.json; tests/data/cycles_instances.json
is a copy that tests/test_lsystem_stats.py checks the constant against.
"""
import json
import pathlib
import subprocess
import sys

ROOT = pathlib.Path(__file__).resolve().parents[1]
OUT = ROOT / "benchmarks" / "charts" / "cycles_instances.json"
COUNTS = [10_000, 100_000, 300_000]

_CHILD = r"""
import json, math, resource, sys, time
import bpy
n = int(sys.argv[1])
bpy.ops.wm.read_factory_settings(use_empty=True)
scene = bpy.context.scene
scene.render.engine = "CYCLES"
scene.cycles.samples = 1
scene.cycles.device = "CPU"
scene.render.threads_mode = "FIXED"
scene.render.threads = 1
scene.render.resolution_x = scene.render.resolution_y = 32
side = math.ceil(math.sqrt(n))
verts = [((i % side) * 0.1, (i // side) * 0.1, 0.0) for i in range(n)]
grid = bpy.data.meshes.new("grid")
grid.from_pydata(verts, [], [])
holder = bpy.data.objects.new("holder", grid)
holder.instance_type = "VERTS"
scene.collection.objects.link(holder)
bpy.ops.mesh.primitive_ico_sphere_add(subdivisions=1, radius=0.03)
ball = bpy.context.active_object
ball.parent = holder
cam = bpy.data.objects.new("cam", bpy.data.cameras.new("cam"))
cam.location = (side * 0.05, side * 0.05, side * 0.2)
scene.collection.objects.link(cam)
scene.camera = cam
bpy.context.view_layer.update()
instances = sum(1 for i in bpy.context.evaluated_depsgraph_get().object_instances if i.is_instance)
before = resource.getrusage(resource.RUSAGE_SELF).ru_maxrss
t0 = time.perf_counter()
bpy.ops.render.render()
seconds = time.perf_counter() - t0
after = resource.getrusage(resource.RUSAGE_SELF).ru_maxrss
print("RESULT", json.dumps({"instances": instances, "added_bytes": (after - before) * 1024,
                            "render_seconds": seconds}))
"""


def measure(n):
    r = subprocess.run([sys.executable, "-c", _CHILD, str(n)], capture_output=True, text=True,
                       timeout=600)
    line = next((ln for ln in r.stdout.splitlines() if ln.startswith("RESULT ")), None)
    if line is None:
        raise RuntimeError(f"the Cycles child failed for {n} instances: {r.stderr[-2000:]}")
    return json.loads(line[len("RESULT "):])


def main():
    import bpy
    rows = [measure(n) for n in COUNTS]
    for row in rows:
        print(f"{row['instances']:>8,} instances: +{row['added_bytes'] / 2**20:7.1f} MiB, "
              f"render {row['render_seconds']:.2f} s")
    a, b = rows[-2], rows[-1]
    per = (b["added_bytes"] - a["added_bytes"]) / (b["instances"] - a["instances"])
    print(f"Cycles: {per:.0f} bytes per instance (slope between the two largest counts)")
    out = {"bytes_per_instance": per, "rows": rows, "blender": bpy.app.version_string,
           "command": "python -m benchmarks.bench_cycles_instances"}
    OUT.write_text(json.dumps(out, indent=1) + "\n")
    return out


if __name__ == "__main__":
    main()
