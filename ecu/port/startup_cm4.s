/* startup_cm4.s - vector table and reset for the replayer on the Cortex-M4 (QEMU mps2-an386):
 * initial stack pointer and reset vector; reset enters newlib's semihosting crt0 (_start). */
    .syntax unified
    .thumb
    .section .vectors, "a"
    .word __stack_top
    .word Reset_Handler
    .text
    .thumb_func
    .global Reset_Handler
Reset_Handler:
    ldr r0, =__stack_top
    mov sp, r0
    b _start
