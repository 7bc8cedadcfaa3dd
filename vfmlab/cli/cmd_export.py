"""``vfmlab export``: deformed meshes and fields per step for ParaView (legacy VTK or PLY)."""

from __future__ import annotations

from pathlib import Path

import click

from vfmlab.cli._common import CliError, CliInputError, console, esc, print_json
from vfmlab.cli._outputs import check_output_dir
from vfmlab.cli._sessions import cli_session, latest_markers


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
@click.option("--format", "fmt", type=click.Choice(["vtk", "ply"]), default="vtk", show_default=True,
              help="vtk: legacy ASCII VTK polydata with strain/stress cell data (+ .vtk.series index); "
                   "ply: binary PLY with E11 face colours and the fields as face properties.")
@click.option("--markers", "markers_name", help="Markers result to export [default: the latest].")
@click.option("--force", is_flag=True, help="Write into an existing, non-empty output folder (its files of the same name are replaced).")
@click.option("--json", "as_json", is_flag=True, help="Print the files written as JSON.")
def command(session, out, fmt, markers_name, force, as_json):
    """Export the marker mesh of SESSION at every step, with E11/E22/E12 strains and each identified
    model's stresses as cell data, in files ParaView opens, and the latest parameter profile along the axis
    ('vfmlab identify --regions') as CSV and a VTK polyline. Lengths in m, stresses in Pa."""
    from vfmlab.export import export_fields, export_profile
    from vfmlab.fields import FieldsError, compute_fields

    path = Path(session)
    out_dir = Path(out) if out else path.with_name(path.stem + "_export")
    check_output_dir(out_dir, force=force, inputs=[path])
    with cli_session(path) as s:
        if markers_name:
            if markers_name not in s.results("markers"):
                raise CliInputError(f"{path}: no markers result {markers_name!r}; markers results are "
                               f"{', '.join(s.results('markers')) or 'none'}")
            markers = s.result(markers_name)
        else:
            markers = latest_markers(s)
        latest = {}
        for name in s.results("identification"):
            r = s.result(name)
            latest[(r["attrs"].get("model"), r["attrs"].get("wall"))] = r
        try:
            fields = compute_fields(markers, s.steps, list(latest.values()))
        except (FieldsError, ValueError) as exc:  # MeshError is a ValueError
            raise CliInputError(f"{path}: cannot build the surface fields from {markers['name']}: {exc}") from None
        specimen = s.specimen.specimen_id
        regional = s.latest("regional") if s.results("regional") else None
    try:
        files = export_fields(fields, out_dir, fmt=fmt, specimen=specimen)
        profile = [] if regional is None else export_profile(regional, out_dir, specimen=specimen)
    except OSError as exc:
        raise CliError(f"cannot write to {out_dir}: {exc}") from None
    n_steps = len(fields.positions)
    cell = ["E11", "E22", "E12"] + [f"{n}_s11/_s22 ({st['model']})" for n, st in fields.stress.items()]
    if as_json:
        print_json({"out": str(out_dir), "format": fmt, "markers_result": markers["name"], "n_steps": n_steps,
                    "files": [str(f) for f in files], "profile_files": [str(f) for f in profile],
                    "profile_result": None if regional is None else regional["name"],
                    "units": {"length": "m", "stress": "Pa", "strain": "1"}})
        return
    console.print(f"Exported {n_steps} steps ({len(fields.mesh.triangles)} triangles, from {esc(markers['name'])}) "
                  f"as {fmt.upper()} to [bold]{esc(out_dir)}[/]; cell data: {esc(', '.join(cell))} "
                  "(files in SI: lengths in m, stresses in Pa, strains dimensionless).")
    if profile:
        console.print(f"Parameter profile along the axis ({esc(regional['name'])}): {esc(profile[0].name)} and "
                      f"{esc(profile[1].name)} (Z and positions in m, parameters in Pa, 95 % intervals).")
    if fmt == "vtk":
        console.print(f"Open {esc(files[-1].name)} (or the {esc(files[0].stem[:-4])}_*.vtk group) in ParaView.")
