from dualid.cli import app

app(prog_name="dualid")
