fn main() {
    println!("reachgrasp: the service shell is not built yet");
}
