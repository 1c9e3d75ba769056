// `sqlx::migrate!` embeds `migrations/` at compile time; without this a new migration file
// (no Rust file changed) leaves the previously embedded set in the binary.
fn main() {
    println!("cargo:rerun-if-changed=migrations");
}
