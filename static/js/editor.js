/* The program editor (templates/missions/editor.html): CodeMirror with JavaScript highlighting
 * on the program box, "Check" (POST /vvs/check/, the same syntax check as the upload: the
 * error's line is marked in the editor), loading a .js file into the editor, and a check
 * before submitting, so that a program with a syntax error is shown, not sent (the server
 * checks again anyway).
 *
 * State for whoever looks (tests): data-check on the form: "", "checking", "ok" or "error";
 * window.cpccEditor is the CodeMirror instance. */
(function () {
  'use strict';

  document.addEventListener('DOMContentLoaded', function () {
    var form = document.getElementById('editor-form');
    if (!form) return;
    var textarea = form.querySelector('textarea[name=program]');
    var nameInput = form.querySelector('input[name=name]');
    var fileInput = form.querySelector('input[type=file]');
    var result = document.getElementById('check-result');
    var checkButton = document.getElementById('check-button');
    var csrf = form.querySelector('input[name=csrfmiddlewaretoken]').value;

    var editor = null;
    if (window.CodeMirror) {
      editor = window.CodeMirror.fromTextArea(textarea, {
        mode: 'javascript', lineNumbers: true, matchBrackets: true, indentUnit: 2, tabSize: 2,
        gutters: ['cm-error-gutter-col', 'CodeMirror-linenumbers'],
        extraKeys: { 'Ctrl-Enter': function () { check(); }, 'Cmd-Enter': function () { check(); } }
      });
      window.cpccEditor = editor;
    }
    function program() { return editor ? editor.getValue() : textarea.value; }
    function setProgram(text) { if (editor) editor.setValue(text); else textarea.value = text; }

    var marked = null; // {line, mark}
    function unmark() {
      if (!marked || !editor) { marked = null; return; }
      editor.removeLineClass(marked.line, 'background', 'cm-error-line');
      editor.setGutterMarker(marked.line, 'cm-error-gutter-col', null);
      if (marked.mark) marked.mark.clear();
      marked = null;
    }
    function mark(line, column) {
      unmark();
      if (!editor) return;
      var l = Math.max(0, Math.min(editor.lineCount() - 1, line - 1));
      var text = editor.getLine(l);
      var c = Math.max(0, Math.min(text.length, column - 1));
      editor.addLineClass(l, 'background', 'cm-error-line');
      var gutter = document.createElement('span');
      gutter.className = 'cm-error-gutter';
      gutter.textContent = '●';
      gutter.title = 'syntax error';
      editor.setGutterMarker(l, 'cm-error-gutter-col', gutter);
      var to = Math.min(text.length, c + 1);
      var m = to > c ? editor.markText({ line: l, ch: c }, { line: l, ch: to }, { className: 'cm-error-mark' }) : null;
      marked = { line: l, mark: m };
      editor.scrollIntoView({ line: l, ch: c }, 80);
      editor.setCursor({ line: l, ch: c });
    }

    function say(kind, text) {
      result.className = 'check-result' + (kind ? ' ' + kind : '');
      result.textContent = text;
    }

    var checkedText = null;
    function check() {
      var text = program();
      form.dataset.check = 'checking';
      say('', 'Checking…');
      checkButton.disabled = true;
      return fetch(form.dataset.checkUrl, {
        method: 'POST',
        credentials: 'same-origin',
        headers: { 'Content-Type': 'application/json', 'X-CSRFToken': csrf },
        body: JSON.stringify({ program: text })
      }).then(function (response) {
        if (!response.ok) throw new Error('the check answered ' + response.status);
        return response.json();
      }).then(function (answer) {
        checkedText = text;
        if (answer.ok) {
          unmark();
          form.dataset.check = 'ok';
          say('ok', 'No syntax error.');
        } else {
          mark(answer.line, answer.column);
          form.dataset.check = 'error';
          say('bad', 'Line ' + answer.line + ', column ' + answer.column + ': ' + answer.message);
        }
        return answer.ok;
      }).catch(function (error) {
        form.dataset.check = '';
        say('bad', 'Could not check the program (' + error.message + '); try again.');
        return null;
      }).then(function (ok) {
        checkButton.disabled = false;
        return ok;
      });
    }

    checkButton.addEventListener('click', function () { check(); });

    if (editor) {
      editor.on('change', function () {
        if (form.dataset.check) {
          unmark();
          form.dataset.check = '';
          say('', '');
        }
      });
    }

    if (fileInput) {
      fileInput.addEventListener('change', function () {
        var file = fileInput.files && fileInput.files[0];
        if (!file) return;
        file.text().then(function (text) {
          setProgram(text.replace(/^\ufeff/, ''));
          if (!nameInput.value.trim()) nameInput.value = file.name.replace(/\.m?js$/i, '');
          say('', 'Loaded ' + file.name + ' (' + text.split('\n').length + ' lines).');
          // The editor holds it now: do not upload the file as well.
          fileInput.value = '';
        });
      });
    }

    // Submit only a program that parses: check first (unless this very text was checked).
    form.addEventListener('submit', function (event) {
      if (editor) editor.save();
      if (checkedText === program() && form.dataset.check === 'ok') return;
      event.preventDefault();
      check().then(function (ok) {
        if (ok === true || ok === null) { // the server checks when we could not
          if (editor) editor.save();
          form.submit();
        }
      });
    });

    // A syntax error the server found (on submit): mark it as a check would.
    if (form.dataset.errorLine) {
      mark(Number(form.dataset.errorLine), Number(form.dataset.errorColumn || 1));
      form.dataset.check = 'error';
      checkedText = program();
    }
  });
})();
