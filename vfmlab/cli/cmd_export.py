"""``vfmlab export``: deformed meshes and fields per step for ParaView, PyVista and meshio (VTU + PVD, legacy VTK
or PLY); the stage is :func:`vfmlab.stages.outputs.export`."""

from __future__ import annotations

from pathlib import Path

import click

from vfmlab.cli._common import console, esc, print_json
from vfmlab.cli._outputs import check_output_dir


EPILOG = """
\b
Examples:
  vfmlab export a1.h5                          # into a1_export/ next to the session
  vfmlab export a1.h5 -o paraview/ --format ply --markers markers_002 --force
"""


@click.command("export", epilog=EPILOG)
@click.argument("session", type=click.Path(dir_okay=False))
@click.option("-o", "--out", "out", type=click.Path(file_okay=False),
              help="Output directory [default: <SESSION stem>_export next to the session].")
@click.option("--format", "fmt", type=click.Choice(["vtu", "vtk", "ply"]), default="vtu", show_default=True,
              help="vtu: VTK XML per step with strain/stress cell data named by model and component, and .pvd "
                   "series (time = pressure in Pa per block; clock time); vtk: legacy ASCII polydata "
                   "(+ .vtk.series, time = step); ply: binary PLY with hoop-strain face colours.")
@click.option("--markers", "markers_name", help="Markers result to export [default: the latest].")
@click.option("--force", is_flag=True, help="Write into an existing, non-empty output folder (its files of the same name are replaced).")
@click.option("--json", "as_json", is_flag=True, help="Print the files written as JSON.")
def command(session, out, fmt, markers_name, force, as_json):
    """Export the marker mesh of SESSION at every step, with E11/E22/E12 strains and each identified
    model's stresses as cell data, in files ParaView opens, and the latest parameter profile along the axis
    ('vfmlab identify --regions') as CSV and a VTK polyline. Lengths in m, stresses in Pa."""
    from vfmlab.stages.outputs import default_out, export
    from vfmlab.stages.settings import ExportSettings

    out_dir = default_out(session, out, "export")
    check_output_dir(out_dir, force=force, inputs=[Path(session)])
    o = export(session, ExportSettings(out=out_dir, fmt=fmt, markers_name=markers_name))
    from vfmlab.export import field_names

    cell = field_names(o.fields, fmt)
    if as_json:
        print_json(o.to_dict())
        return
    console.print(f"Exported {len(o.fields.positions)} steps ({len(o.fields.mesh.triangles)} triangles, from "
                  f"{esc(o.markers_result)}) as {fmt.upper()} to [bold]{esc(out_dir)}[/]; cell data: "
                  f"{esc(', '.join(cell))} (files in SI: lengths in m, stresses in Pa, strains dimensionless).")
    if o.profile:
        console.print(f"Parameter profile along the axis ({esc(o.profile_result)}): {esc(o.profile[0].name)} and "
                      f"{esc(o.profile[1].name)} (Z and positions in m, parameters in Pa, 95 % intervals).")
    if fmt == "vtk":
        console.print(f"Open {esc(o.files[-1].name)} (or the {esc(o.files[0].stem[:-4])}_*.vtk group) in ParaView.")
    elif fmt == "vtu":
        pvd = [p.name for p in o.files if p.suffix == ".pvd"]
        console.print(f"Open {esc(', '.join(pvd))} in ParaView or PyVista (time = pressure in Pa per block; "
                      "clock seconds in the _clock series); each .vtu reads with meshio.")
