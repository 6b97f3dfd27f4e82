"""``orange-plan range``: operational range and energy breakdown."""

from __future__ import annotations

from rich.table import Table

from orange_plan.cli import JsonOpt, ScenarioArg, app, handles_errors, out, print_json


@app.command("range")
@handles_errors
def range_cmd(scenario: ScenarioArg, as_json: JsonOpt = False) -> None:
    """Operational range: d_max, v_opt and where the energy goes (Eq. 3, 4, 6, 11)."""
    from orange_plan.context import load_context
    from orange_plan.range_report import range_report

    report = range_report(load_context(scenario))
    if as_json:
        print_json(report.to_dict())
        return
    out.print(_range_table(report))
    if report.simplified.reason:
        out.print(f"[yellow]{report.simplified.reason}[/]")


def _range_table(report) -> Table:
    e, s, g = report.energy, report.simplified, report.generalised
    table = Table(title=f"Operational range: {report.scenario} ({report.robot_kind})",
                  show_header=True, header_style="bold")
    table.add_column("quantity")
    table.add_column("value", justify="right")
    table.add_column("note")
    rows = [
        ("d_max", f"{s.d_max_m:,.1f} m", f"simplified ORangE, Eq. 6, flat ground crr={report.crr:g}"),
        ("v_opt", f"{s.v_opt_mps:.3f} m/s", "speed in \\[v_min, v_max] maximising range"),
        ("mission time", f"{s.mission_time_s / 60:,.1f} min", _time_note(report)),
        ("energy per metre", f"{s.energy_per_m_J:,.2f} J/m", ""),
        ("d_max (generalised)", f"{g.d_max_m:,.1f} m",
         f"offline Eq. 11 over the map at {g.v_opt_mps:.3f} m/s (wind, grades, surfaces)"),
        *_time_limited_rows(s, g),
        ("", "", ""),
        ("rated energy", f"{e.rated_J / 1e3:,.2f} kJ", "E_O"),
        ("capacity decay", f"{e.decay_J / 1e3:,.2f} kJ", "Eq. 3: cycles and age"),
        ("battery loss eta_1", f"{e.battery_loss_eta1_J / 1e3:,.2f} kJ", "self-discharge"),
        ("available", f"{e.available_J / 1e3:,.2f} kJ", "E_avail = ancillary + traversal"),
        ("  ancillary", f"{e.ancillary_J / 1e3:,.2f} kJ",
         f"P_anc = {report.ancillary_power_W:.2f} W for the mission time"),
        ("    ancillary loss eta_4", f"{e.ancillary_loss_eta4_J / 1e3:,.2f} kJ", ""),
        ("  traversal", f"{e.traversal_J / 1e3:,.2f} kJ", f"ME / Omega, Omega = {report.omega:.3f}"),
        ("    motor loss eta_2", f"{e.motor_loss_eta2_J / 1e3:,.2f} kJ", ""),
        ("    mechanical loss eta_3", f"{e.mechanical_loss_eta3_J / 1e3:,.2f} kJ", ""),
        ("    mechanical work", f"{e.mechanical_work_J / 1e3:,.2f} kJ", "rolling + drag (ME)"),
    ]

    for row in rows:
        table.add_row(*row)
    return table


def _time_note(report) -> str:
    note = "stops included (duty cycle)"
    if report.time_limit_s is None:
        return note
    if report.simplified.within_time_limit:
        return f"{note}; within mission.time_limit_s = {report.time_limit_s:g} s"
    return f"[red]exceeds mission.time_limit_s = {report.time_limit_s:g} s[/]"


def _time_limited_rows(simplified, generalised) -> list[tuple[str, str, str]]:
    """Rows for the ranges the time limit allows (none when both fit)."""
    rows = []
    for label, r in (("d_max within time limit", simplified),
                     ("d_max (generalised) within time limit", generalised)):
        if r.time_limited is not None:
            t = r.time_limited
            rows.append((label, f"{t.d_max_m:,.1f} m", f"at {t.v_opt_mps:.3f} m/s, mission time "
                         f"{t.mission_time_s / 60:,.1f} min"))
    return rows
