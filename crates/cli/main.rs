//! `activemap`: the command-line entry point (see `activemap --help`).

fn main() -> anyhow::Result<()> {
    anyhow::bail!("activemap: no command implemented yet")
}
