"""Run in a fresh Python by tests/test_usd_env.py: every UsdValidation validator on every
``lod`` selection of each asset named on the command line, without importing usdbtf.

Prints one JSON object: {"assets": {path: {selection: [issue, ...]}}, "validators": n,
"schema_known": bool, "shader_known": bool, "usdbtf_imported": bool}.  Selection "" is
the stage as authored.
"""
import json
import sys

from pxr import Sdr, Usd, UsdValidation

LOD = "lod"


def issues(stage):
    validators = UsdValidation.ValidationRegistry().GetOrLoadAllValidators()
    # A USD without MaterialX (usd-core) has no Sdr entry for any MaterialX node (the OpenPBR
    # fallback's ND_* ids); tests/mtlx_usd_validate.py checks them in a USD with MaterialX.
    materialx = "ND_standard_surface_surfaceshader" in Sdr.Registry().GetShaderNodeIdentifiers()
    out = []
    for err in UsdValidation.ValidationContext(validators).Validate(stage):
        if not materialx and "MissingShaderIdInRegistry" in str(err.GetIdentifier()) and \
                "shaderId 'ND_" in err.GetMessage():
            continue
        if not err.HasNoError():
            out.append(f"{str(err.GetType()).rsplit('.', 1)[-1]} [{err.GetIdentifier()}] {err.GetMessage()}")
    return out


def lod_names(stage):
    names = []
    for prim in stage.Traverse():
        sets = prim.GetVariantSets()
        if sets.HasVariantSet(LOD):
            names += [n for n in sets.GetVariantSet(LOD).GetVariantNames() if n not in names]
    return names


def select(stage, name):
    with Usd.EditContext(stage, stage.GetSessionLayer()):
        for prim in stage.Traverse():
            sets = prim.GetVariantSets()
            if sets.HasVariantSet(LOD) and name in sets.GetVariantSet(LOD).GetVariantNames():
                sets.GetVariantSet(LOD).SetVariantSelection(name)


def main(paths):
    report = {}
    for path in paths:
        stage = Usd.Stage.Open(path)
        per = {"": issues(stage)}
        for name in lod_names(stage):
            fresh = Usd.Stage.Open(path)
            select(fresh, name)
            per[name] = issues(fresh)
        report[path] = per
    print(json.dumps({
        "assets": report,
        "validators": len(UsdValidation.ValidationRegistry().GetOrLoadAllValidators()),
        "schema_known": Usd.SchemaRegistry().FindAppliedAPIPrimDefinition("BtfMaterialAPI") is not None,
        "shader_known": Sdr.Registry().GetShaderNodeByIdentifier("UsdBtfSurface") is not None,
        "usdbtf_imported": any(m == "usdbtf" or m.startswith("usdbtf.") for m in sys.modules),
    }))


if __name__ == "__main__":
    main(sys.argv[1:])
