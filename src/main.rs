use clap::Parser;

fn main() {
    let cli = tunnelnav::cli::Cli::parse();
    if let Err(e) = tunnelnav::cli::run(cli) {
        eprintln!("error: {e}");
        std::process::exit(2);
    }
}
