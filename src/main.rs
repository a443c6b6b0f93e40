//! The `candeck` binary: everything lives in the library (`candeck::cli`).

fn main() -> std::process::ExitCode {
    candeck::cli::main()
}
