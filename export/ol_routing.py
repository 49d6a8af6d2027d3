"""Orientation lightmaps (thesis ch. 6): which OL empty receives each exported instance's hits.

An Empty with `orientation_lightmap` set is an OL attached to the collection
`ol_collection` (never geometry). Each exported instance goes to the innermost
OL collection holding it (child collections included; collection-instance and
particle duplis follow their instancer object); OLs nest as their collections
do (fig. 6.3).
"""
from ..engine.core.scene import OrientationLightmap


def is_orientation_lightmap(ob):
    """True for an Empty tagged as an orientation lightmap (ui/properties.py)."""
    props = getattr(ob, "photon_lightmaps", None) if ob is not None else None
    return ob is not None and ob.type == "EMPTY" and props is not None and bool(props.orientation_lightmap)


class OLRouter:
    """Which OL empty receives each instance's hits, following the collection tree.

    Works on original datablocks keyed by pointer (names may repeat across
    libraries). The innermost OL collection of an object is the one among
    those holding it that the others all contain."""

    def __init__(self, bscene, report):
        self.report = report
        scene = getattr(bscene, "original", None) or bscene
        in_scene = {c.as_pointer() for c in scene.collection.children_recursive}
        by_coll = {}
        for ob in sorted(scene.objects, key=lambda o: o.name):
            if not is_orientation_lightmap(ob):
                continue
            coll = ob.photon_lightmaps.ol_collection
            if coll is None:
                report("WARNING", f"orientation lightmap '{ob.name}' has no collection: it is ignored "
                                  "(set one in its Photon Lightmap panel, or remove it)")
                continue
            if coll.as_pointer() not in in_scene:
                report("WARNING", f"orientation lightmap '{ob.name}': collection '{coll.name}' is not "
                                  f"in scene '{scene.name}', so it covers nothing here")
                continue
            by_coll.setdefault(coll.as_pointer(), []).append(ob)
        self.colls = {}       # collection pointer -> (collection, OL empty)
        for key, obs in by_coll.items():
            if len(obs) > 1:
                report("WARNING", f"collection '{obs[0].photon_lightmaps.ol_collection.name}' has "
                                  f"{len(obs)} orientation lightmaps ({', '.join(repr(o.name) for o in obs)}): "
                                  f"only '{obs[0].name}' is used; remove the others")
            self.colls[key] = (obs[0].photon_lightmaps.ol_collection, obs[0])
        # contains[a] = OL collections inside a (recursively); members[a] = its objects
        self.members = {k: {o.as_pointer() for o in c.all_objects} for k, (c, _) in self.colls.items()}
        self.inside = {k: {d.as_pointer() for d in c.children_recursive} & set(self.colls)
                       for k, (c, _) in self.colls.items()}
        self.depth = {k: sum(k in self.inside[a] for a in self.colls) for k in self.colls}
        self.instances = {k: [] for k in self.colls}
        self._cache = {}

    def __bool__(self):
        return bool(self.colls)

    def route(self, owner):
        """Collection pointer of the innermost OL holding object `owner` (original), or None."""
        if owner is None or not self.colls:
            return None
        key = owner.as_pointer()
        if key in self._cache:
            return self._cache[key]
        cands = [k for k in self.colls if key in self.members[k]]
        best = None
        if cands:
            deepest = max(self.depth[k] for k in cands)
            top = sorted((k for k in cands if self.depth[k] == deepest), key=lambda k: self.colls[k][1].name)
            best = top[0]
            if len(top) > 1:
                self.report("WARNING", f"object '{owner.name}' is in unrelated orientation lightmap "
                                       f"collections ({', '.join(repr(self.colls[k][0].name) for k in top)}): "
                                       f"its hits go to '{self.colls[best][1].name}' only; nest them instead")
        self._cache[key] = best
        return best

    def add(self, key, instance_id):
        self.instances[key].append(instance_id)

    def build(self, seed=0):
        """Engine OrientationLightmaps (parents before children) and their ExportMap rows."""
        parent = {}
        for k in self.colls:
            outer = [a for a in self.colls if k in self.inside[a]]
            parent[k] = max(outer, key=lambda a: (self.depth[a], self.colls[a][1].name)) if outer else None
        order = sorted(self.colls, key=lambda k: (self.depth[k], self.colls[k][1].name))
        index, ols, rows = {}, [], []
        for k in order:
            coll, empty = self.colls[k]
            s = empty.photon_lightmaps
            p = parent[k]
            res = int(s.ol_resolution)
            if p is not None:
                # A parent's bins are the sum of its children's, so a hierarchy shares one layout.
                res = ols[index[p]].resolution
                if res != int(s.ol_resolution):
                    self.report("WARNING", f"orientation lightmap '{empty.name}' uses resolution {res} of "
                                           f"its enclosing '{self.colls[p][1].name}' (its own setting "
                                           f"{int(s.ol_resolution)} is ignored)")
            if not self.instances[k] and not any(parent[c] == k for c in self.colls):
                self.report("WARNING", f"orientation lightmap '{empty.name}': collection '{coll.name}' "
                                       "holds no exported geometry, so it receives no photons")
            index[k] = len(ols)
            ols.append(OrientationLightmap(name=empty.name, instances=list(self.instances[k]),
                                           parent=index[p] if p is not None else -1, resolution=res,
                                           samples=int(s.ol_samples), min_hits=int(s.ol_min_hits),
                                           backup=bool(s.ol_backup), seed=int(seed) + len(ols)))
            rows.append({"empty": empty.name, "collection": coll.name,
                         "parent": self.colls[p][1].name if p is not None else None,
                         "instances": list(self.instances[k])})
        return ols, rows


