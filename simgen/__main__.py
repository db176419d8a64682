from simgen.cli import app

app(prog_name="simgen")
