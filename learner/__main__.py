from learner.cli import app

app(prog_name="learner")
